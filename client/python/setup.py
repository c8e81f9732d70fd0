"""Generates the gRPC stubs from the API's .proto files while the package is built.

The stubs are never checked in: build_py runs protoc on proto/riccati/v1/*.proto
(the repository's, or RICCATI_PROTO_DIR's) with Debian's grpc_python_plugin
(protobuf-compiler-grpc), writing riccati/v1/*_pb2.py and *_pb2_grpc.py into
the build, beside the hand-written package. protoc's generated imports
("from riccati.v1 import common_pb2") then resolve inside this package.
"""
import glob
import os
import shutil
import subprocess

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))


def proto_dir():
    candidates = [os.environ.get("RICCATI_PROTO_DIR", ""), os.path.join(HERE, "..", "..", "proto")]
    for path in candidates:
        if path and os.path.isdir(os.path.join(path, "riccati", "v1")):
            return os.path.abspath(path)
    raise SystemExit("riccati: cannot find the API's .proto files (proto/riccati/v1 beside client/python, "
                     "or set RICCATI_PROTO_DIR)")


def tool(name, env, package):
    path = os.environ.get(env) or shutil.which(name)
    if not path:
        raise SystemExit(f"riccati: {name} not found (Debian: apt-get install {package}; or set {env})")
    return path


class BuildWithStubs(build_py):
    def run(self):
        super().run()
        if self.dry_run:
            return
        protos = proto_dir()
        out = os.path.join(self.build_lib, "riccati", "v1")
        shutil.rmtree(out, ignore_errors=True)  # no stub of a .proto that is gone
        os.makedirs(out)
        files = sorted(glob.glob(os.path.join(protos, "riccati", "v1", "*.proto")))
        subprocess.run([tool("protoc", "RICCATI_PROTOC", "protobuf-compiler"), f"-I{protos}",
                        f"--python_out={self.build_lib}", f"--grpc_python_out={self.build_lib}",
                        "--plugin=protoc-gen-grpc_python=" +
                        tool("grpc_python_plugin", "RICCATI_GRPC_PYTHON_PLUGIN", "protobuf-compiler-grpc"),
                        *[os.path.relpath(f, protos) for f in files]], check=True)
        with open(os.path.join(out, "__init__.py"), "w") as init:
            init.write('"""riccati.v1: the gRPC stubs, generated from proto/riccati/v1 when the package was built."""\n')


setup(cmdclass={"build_py": BuildWithStubs})

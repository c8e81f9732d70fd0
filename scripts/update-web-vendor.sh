#!/usr/bin/env bash
# Refreshes the workbench's vendored uPlot (client/web/vendor/uplot) from the
# npm registry, at the version and integrity hash client/web/package-lock.json
# pins (npm ci checks the hash). Only for whoever changes the version: the
# build embeds the vendored files and needs neither npm nor the internet.
#   edit client/web/package.json's version; npm install --package-lock-only; scripts/update-web-vendor.sh
set -euo pipefail
cd "$(dirname "$0")/../client/web"
npm ci --ignore-scripts --no-audit --no-fund
mkdir -p vendor/uplot
cp node_modules/uplot/dist/uPlot.esm.js node_modules/uplot/dist/uPlot.min.css node_modules/uplot/LICENSE vendor/uplot/
version=$(node -p 'require("./node_modules/uplot/package.json").version')
echo "uPlot $version (MIT, by Leon Sorokin): https://github.com/leeoniya/uPlot" > vendor/uplot/VERSION
rm -rf node_modules
echo "vendored uPlot $version in client/web/vendor/uplot"

#!/usr/bin/env bash
# Builds CesiumGS's 3d-tiles-validator into .validator/ (ignored by git) for the interop tests
# (tests/io/test_validator.py). Idempotent: a no-op once .validator/build/main.js exists.
#
# The npm registry does not serve the validator under its own name, so its TypeScript source is vendored
# (third_party/3d-tiles-validator/, Apache-2.0, commit 7fa62c5f of the CesiumGS repository) and compiled
# here against 3d-tiles-tools 0.5.4 and sharp 0.33.5 from npm, the versions the validator is known to build
# and run with. Needs node >= 18 and npm; where either is missing, or npm cannot install, it prints the
# reason and exits 0 so `make test` goes on (the tests then skip, naming the reason).
set -uo pipefail
cd "$(dirname "$0")/.."
dest=.validator
tarball=third_party/3d-tiles-validator/3d-tiles-validator-7fa62c5f.tar.gz
[ -f "$dest/build/main.js" ] && exit 0

skip() { echo "3d-tiles-validator not built: $*" >&2; echo "$*" > "$dest.skipped"; exit 0; }
command -v node >/dev/null || skip "node is not installed"
command -v npm >/dev/null || skip "npm is not installed"
major=$(node -p 'process.versions.node.split(".")[0]')
[ "$major" -ge 18 ] || skip "node $major is older than 18"

rm -rf "$dest" "$dest.skipped"
mkdir -p "$dest"
tar -xzf "$tarball" -C "$dest" --strip-components=1 || skip "cannot unpack $tarball"
# Pin the two dependencies the vendored package.json names too loosely; drop the dev tools the tests
# do not need (linters, doc generators), keeping the compiler and the Node typings.
node - "$dest/package.json" <<'EOF' || skip "cannot rewrite package.json"
const fs = require("fs");
const file = process.argv[2];
const pkg = JSON.parse(fs.readFileSync(file, "utf8"));
pkg.dependencies["3d-tiles-tools"] = "0.5.4";
pkg.dependencies["sharp"] = "0.33.5";
// Every sharp in the tree at 0.33.5, whose native part comes from npm (@img/sharp-*): older ones, pulled in
// through ndarray-pixels, download libvips from outside the registry at install time.
pkg.overrides = { "sharp": "0.33.5" };
// One glTF-Transform for both: 3d-tiles-tools 0.5.4 passes its 4.x Documents to the validator's code.
for (const p of ["core", "extensions", "functions"]) pkg.dependencies["@gltf-transform/" + p] = "^4.4.0";
pkg.devDependencies = { "typescript": "^4.8.3", "@types/node": "^20.0.0", "@types/minimatch": "^5.1.2" };
delete pkg.scripts;
fs.writeFileSync(file, JSON.stringify(pkg, null, 2));
EOF
echo "building 3d-tiles-validator in $dest (npm install, tsc)"
(cd "$dest" && npm install --no-audit --no-fund --loglevel=error >npm-install.log 2>&1) \
  || skip "npm install failed (see $dest/npm-install.log)"
(cd "$dest" && npx tsc >tsc.log 2>&1) || skip "the TypeScript build failed (see $dest/tsc.log)"
cp "$dest/bin/main" "$dest/build/main"
node "$dest/build/main.js" --help >/dev/null 2>&1 || skip "the built validator does not start"
echo "3d-tiles-validator built: node $dest/build/main.js --tilesetFile TILESET.json"

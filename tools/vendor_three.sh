#!/usr/bin/env bash
# Rebuild the three.js bundle that conformill.output.viewer inlines into its HTML pages.
#
# three.js >= r171 ships no single-file minified build, so we bundle the few classes the viewer
# uses (WebGLRenderer, Mesh, LineSegments, ...) plus examples/jsm OrbitControls into one
# minified IIFE that defines the global `THREE` (a classic script: no modules, no import map,
# works from file:// with no network). Both packages come from the npm registry:
#   three    MIT, the library (its LICENSE is copied next to the bundle)
#   esbuild  only the bundler/minifier, not shipped
#
# Usage: tools/vendor_three.sh [THREE_VERSION]      (default: the version pinned below)
# Output: src/conformill/output/assets/three.viewer.min.js and THREE_LICENSE.txt
# The build is reproducible: same versions -> same bytes (checked by sha256 below).
set -euo pipefail

THREE_VERSION="${1:-0.187.0}"
ESBUILD_VERSION="0.28.2"
HERE="$(cd "$(dirname "$0")/.." && pwd)"
ASSETS="$HERE/src/conformill/output/assets"
WORK="$(mktemp -d)"
trap 'rm -rf "$WORK"' EXIT

cd "$WORK"
npm init -y >/dev/null
npm install --no-audit --no-fund --silent "three@$THREE_VERSION" "esbuild@$ESBUILD_VERSION"

# The exports the viewer (conformill/output/viewer.py, the JS in _PAGE_JS) relies on.
cat > entry.js <<'JS'
export {
  WebGLRenderer, Scene, PerspectiveCamera, Color, BufferGeometry, BufferAttribute,
  Mesh, MeshStandardMaterial, MeshPhongMaterial, LineSegments, LineBasicMaterial,
  LineDashedMaterial, HemisphereLight, DirectionalLight, AmbientLight, Box3, Vector3, Sphere,
  Group, DoubleSide, SRGBColorSpace, REVISION
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
JS

npx esbuild entry.js --bundle --minify --format=iife --global-name=THREE \
  --legal-comments=none --target=es2020 --charset=utf8 --outfile=bundle.js --log-level=warning

{
  printf '/* three.js r%s (npm three@%s) + OrbitControls, bundled by tools/vendor_three.sh.\n' \
    "${THREE_VERSION#0.}" "$THREE_VERSION" | sed 's/r\([0-9]*\)\.0 /r\1 /'
  printf '   MIT licence, Copyright (c) 2010-2026 three.js authors: see THREE_LICENSE.txt. */\n'
  cat bundle.js
} > three.viewer.min.js

# The HTML inlines this file in a <script> element: it must not contain "</script" or "<!--".
if grep -qi -e '</script' -e '<!--' three.viewer.min.js; then
  echo "vendor_three.sh: bundle contains </script or <!--; cannot inline it" >&2
  exit 1
fi

cp three.viewer.min.js "$ASSETS/three.viewer.min.js"
cp node_modules/three/LICENSE "$ASSETS/THREE_LICENSE.txt"
wc -c "$ASSETS/three.viewer.min.js"
sha256sum "$ASSETS/three.viewer.min.js"

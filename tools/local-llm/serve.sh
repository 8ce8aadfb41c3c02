#!/usr/bin/env bash
# Start the local OpenAI-compatible chat server in the foreground on 127.0.0.1.
# Usage: serve.sh [PORT]   (default: $LOCAL_LLM_PORT or 8088)
# Prints the base URL (e.g. http://127.0.0.1:8088) on stdout once it accepts requests;
# logs go to stderr. Stop with Ctrl-C / SIGTERM.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
PORT="${1:-${LOCAL_LLM_PORT:-8088}}"
cd "$HERE"

[ -f "$HERE/node_modules/node-llama-cpp/package.json" ] \
    || { echo "serve: node-llama-cpp is not installed; run $HERE/setup.sh first" >&2; exit 1; }
[ -f "${LOCAL_LLM_MODEL:-models/SmolLM2-135M-Instruct.Q4_1.gguf}" ] \
    || { echo "serve: model file missing; run $HERE/setup.sh first" >&2; exit 1; }

# Never download or build llama.cpp at run time.
export NODE_LLAMA_CPP_SKIP_DOWNLOAD=true
exec node "$HERE/server.mjs" "$PORT"

#!/usr/bin/env bash
# Start the local OpenAI-compatible chat server in the foreground on 127.0.0.1.
# Usage: serve.sh [--model FILE.gguf] [--model-id NAME] [PORT]
#   --model     any GGUF chat model (default: the SmolLM2-135M-Instruct that setup.sh installs;
#               also $LOCAL_LLM_MODEL); a path relative to the working directory or absolute
#   --model-id  the model name the server reports (default: the file name without .gguf)
#   PORT        default $LOCAL_LLM_PORT or 8088
# Prints the base URL (e.g. http://127.0.0.1:8088) on stdout once it accepts requests;
# logs go to stderr. Stop with Ctrl-C / SIGTERM.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
PORT="${LOCAL_LLM_PORT:-8088}"
while [ $# -gt 0 ]; do
    case "$1" in
        --model) [ $# -ge 2 ] || { echo "serve: --model needs a GGUF file" >&2; exit 2; }
                 LOCAL_LLM_MODEL="$(realpath -m "$2")"; export LOCAL_LLM_MODEL; shift 2 ;;
        --model-id) [ $# -ge 2 ] || { echo "serve: --model-id needs a name" >&2; exit 2; }
                 export LOCAL_LLM_MODEL_ID="$2"; shift 2 ;;
        -h|--help) sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        --*) echo "serve: unknown option $1 (see --help)" >&2; exit 2 ;;
        *) PORT="$1"; shift ;;
    esac
done
cd "$HERE"

[ -f "$HERE/node_modules/node-llama-cpp/package.json" ] \
    || { echo "serve: node-llama-cpp is not installed; run $HERE/setup.sh first" >&2; exit 1; }
MODEL="${LOCAL_LLM_MODEL:-models/SmolLM2-135M-Instruct.Q4_1.gguf}"
[ -f "$MODEL" ] || { echo "serve: model file $MODEL missing (run $HERE/setup.sh for the default)" >&2; exit 1; }
# A GGUF file starts with the magic "GGUF": refuse anything else before loading it.
[ "$(head -c 4 "$MODEL")" = "GGUF" ] || { echo "serve: $MODEL is not a GGUF file" >&2; exit 1; }

# Never download or build llama.cpp at run time.
export NODE_LLAMA_CPP_SKIP_DOWNLOAD=true
exec node "$HERE/server.mjs" "$PORT"

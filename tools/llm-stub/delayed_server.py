#!/usr/bin/env python3
"""A stand-in for a slow model: an OpenAI-compatible Chat Completions endpoint on loopback that
answers every request after a fixed delay with `{"target": 0, ...}` (always a valid candidate).

It measures what a model's latency costs the loop (`ask.mode: blocking` against `background`);
it says nothing about the quality of a model's choices.

    python3 tools/llm-stub/delayed_server.py --port 8099 --delay 25
    activemap run flows/llm.yaml --out runs/slow --max-steps 400 --no-eval \\
      --set 'planner.llm={prompt: text, ask: {mode: background},
             provider: {kind: openai, base_url: "http://127.0.0.1:8099/v1", model: stub, timeout_s: 120}}'
"""

import argparse
import json
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=8099)
    parser.add_argument("--delay", type=float, default=25.0, help="seconds per reply")
    args = parser.parse_args()

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802 (the standard library's name)
            length = int(self.headers.get("Content-Length", "0"))
            self.rfile.read(length)
            time.sleep(args.delay)
            content = json.dumps({"target": 0, "reason": "stub: the first candidate"})
            body = json.dumps(
                {
                    "id": "stub",
                    "object": "chat.completion",
                    "model": "stub",
                    "choices": [
                        {
                            "index": 0,
                            "finish_reason": "stop",
                            "message": {"role": "assistant", "content": content},
                        }
                    ],
                    "usage": {"prompt_tokens": 0, "completion_tokens": 0},
                }
            ).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *values: object) -> None:
            pass

    ThreadingHTTPServer(("127.0.0.1", args.port), Handler).serve_forever()


if __name__ == "__main__":
    main()

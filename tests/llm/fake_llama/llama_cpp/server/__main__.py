"""A stand-in for ``python -m llama_cpp.server`` in the default test run (the real one needs the
local-llm extra, an 11-minute build): the same command line, ``/v1/models`` and
``/v1/chat/completions`` on 127.0.0.1, the same failures (a model that does not load, a port in
use: a message and exit status 1), and a helper process in its process group, as a real server's
workers would be, so tests can check that lagrseq stops the whole group. Standard library only."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

ANSWER = "Let me think step by step. The human stacks the red cubes first.\n['a','b','c','d','e','f','g','h']"


def main() -> None:
    parser = argparse.ArgumentParser()
    for name in ("--model", "--model_alias", "--host", "--port", "--n_ctx", "--n_threads", "--seed"):
        parser.add_argument(name, required=name not in ("--model_alias", "--seed"))
    args = parser.parse_args()
    model = Path(args.model)
    if not model.is_file() or model.read_bytes()[:8] != b"GGUF\x03\x00\x00\x00":
        print(f"llama_model_load: error loading model: {model}: invalid or unsupported GGUF file", file=sys.stderr, flush=True)
        raise SystemExit(1)
    alias = args.model_alias or args.model

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *a: Any) -> None:
            print(f"INFO: {self.address_string()} {a[0] % a[1:]}", flush=True)

        def reply(self, payload: dict[str, Any]) -> None:
            data = json.dumps(payload).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def do_GET(self) -> None:
            if self.path == "/v1/models":
                self.reply({"object": "list", "data": [{"id": alias, "object": "model", "owned_by": "me"}]})
            else:
                self.send_error(404)

        def do_POST(self) -> None:
            body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", "0"))))
            prompt = body["messages"][-1]["content"]
            # what a request asked of the sampler, kept where a test can read it (the real server's
            # defaults, top_k 40, min_p 0.05 and repeat_penalty 1.1, apply to what is not sent)
            bodies = os.environ.get("FAKE_LLAMA_BODIES")
            if bodies:
                sampling = {name: body.get(name) for name in ("temperature", "top_p", "top_k", "min_p", "repeat_penalty")}
                with open(bodies, "a", encoding="utf-8") as out:
                    out.write(json.dumps(sampling) + "\n")
            time.sleep(0.05)
            self.reply({
                "id": "chatcmpl-fake", "object": "chat.completion", "created": int(time.time()), "model": alias,
                "choices": [{"index": 0, "message": {"role": "assistant", "content": ANSWER}, "finish_reason": "stop"}],
                "usage": {"prompt_tokens": len(prompt) // 4, "completion_tokens": len(ANSWER) // 4, "total_tokens": len(prompt) // 4 + len(ANSWER) // 4},
            })

    try:
        httpd = ThreadingHTTPServer((args.host, int(args.port)), Handler)
    except OSError as exc:
        print(f"ERROR: [Errno {exc.errno}] error while attempting to bind on address ({args.host!r}, {args.port}): address already in use", file=sys.stderr, flush=True)
        raise SystemExit(1) from None
    helper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3600)"])
    print(f"helper pid {helper.pid}", flush=True)
    print(f"INFO: Uvicorn running on http://{args.host}:{args.port} (model {alias}, n_ctx {args.n_ctx}, threads {args.n_threads})", flush=True)
    httpd.serve_forever()


if __name__ == "__main__":
    main()

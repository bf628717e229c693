"""Cost of refusing expensive launch files, and of checking a good one.

Each bad file is given to `dockhil graph` in its own process: wall time, peak
resident memory and the exit code (2: refused in one line). `hil_load_ms` is
the time to read, check and build launch/hil.yaml in this process. Prints one
JSON object as its last line.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def billion_laughs() -> str:
    lines = ["a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for k in range(1, 9):
        prev, cur = chr(ord("a") + k - 1), chr(ord("a") + k)
        lines.append(f"{cur}: &{cur} [" + ", ".join([f"*{prev}"] * 10) + "]")
    return "\n".join(lines) + "\nnodes: *i\n"


CASES = {
    "alias_bomb": billion_laughs(),
    "nested_20000": "nodes: " + "[" * 20000 + "\n",
    "file_2MB": "description: " + "x" * (2 << 20) + "\n",
    "hil_yaml": open(os.path.join(ROOT, "launch", "hil.yaml"))
    .read()
    .replace("file: emulators.yaml", f"file: {ROOT}/launch/emulators.yaml"),
}


def refuse(text: str, folder: str) -> dict:
    path = os.path.join(folder, "scene.yaml")
    with open(path, "w") as f:
        f.write(text)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "dockhil.cli", "graph", path],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - t0
    stderr = proc.stderr.read().decode()
    proc.stderr.close()
    return {
        "bytes": len(text.encode()),
        "exit_code": os.waitstatus_to_exitcode(status),
        "stderr_lines": len(stderr.strip().splitlines()),
        "seconds": round(seconds, 3),
        "peak_rss_mb": round(usage.ru_maxrss / 1024, 1),
    }


def hil_load_ms(repeats: int = 50) -> float:
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    path = os.path.join(ROOT, "launch", "hil.yaml")
    build(launchfile.load(path))  # imports done once
    t0 = time.perf_counter()
    for _ in range(repeats):
        build(launchfile.load(path))
    return round((time.perf_counter() - t0) / repeats * 1e3, 2)


def main() -> None:
    with tempfile.TemporaryDirectory() as folder:
        out = {name: refuse(text, folder) for name, text in CASES.items()}
    out["hil_load_ms"] = hil_load_ms()
    print(json.dumps(out))


if __name__ == "__main__":
    main()

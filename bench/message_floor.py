"""What the messages of a composed scene cost a tick on their own. Every message the scene's
nodes publish in a run is recorded; then each is screened for non-finite numbers, as the
composed runner checks every output (screen_us_per_tick), and built anew struct by struct from
its values, as a node builds its outputs but with positional arguments, no logic, and the
default nested values shared as a node shares them (build_us_per_tick). No node computes
anything here: with the model's own bare loop added, the screen is a floor under what a composed
tick of the scene can cost, and the build says what making the messages adds to it.

Used by bench/graph.py and bench/hil6.py; prints one JSON object when run alone."""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

# As the dockhil command does: BLAS worker threads only spin on the models' small problems, and
# process time would count them (before numpy is imported).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def rebuilder(cls: type):
    """A function building a message of type `cls` anew from another's values, struct by struct."""
    import msgspec.inspect as mi

    scope: dict = {}

    def expr(t, var: str) -> str:
        if isinstance(t, mi.Metadata):
            t = t.type
        if isinstance(t, mi.StructType):
            name = f"C{len(scope)}"
            scope[name] = t.cls
            return f"{name}({', '.join(field(f, f'{var}.{f.name}') for f in t.fields)})"
        if isinstance(t, (mi.ListType, mi.VarTupleType)):
            item = f"i{len(scope)}"
            scope[item] = None
            items = f"[{expr(t.item_type, item)} for {item} in {var}]"
            return f"tuple({items})" if isinstance(t, mi.VarTupleType) else items  # as msgs build them
        return var

    def field(f, var: str) -> str:
        t = f.type.type if isinstance(f.type, mi.Metadata) else f.type
        if isinstance(t, mi.StructType) and isinstance(f.default, t.cls):  # a default a node would share
            name = f"D{len(scope)}"
            scope[name] = f.default
            return f"({var} if {var} is {name} else {expr(t, var)})"
        return expr(f.type, var)

    body = expr(mi.type_info(cls), "m")
    exec(compile(f"def rebuild(m):\n    return {body}\n", f"<rebuild {cls.__name__}>", "exec"), scope)  # noqa: S102
    return scope["rebuild"]


def messages_of(scene: str, n_ticks: int, args: dict | None = None) -> list[list]:
    """Every message a composed run of `scene` publishes, per tick."""
    from dockhil.runtime.composed import ComposedGraph
    from dockhil.scene import launchfile
    from dockhil.scene.graph import build

    ticks: list[list] = [[] for _ in range(n_ticks)]
    g = ComposedGraph(
        build(launchfile.load(scene, args or {})),
        log=lambda n, m: None,
        taps=[lambda topic, msg: ticks[msg.header.tick].append(msg)],
    )
    g.setup()
    g.run(n_ticks)
    g.close()
    return ticks


def cost_us_per_tick(ticks: list[list], repeat: int = 5) -> dict[str, float]:
    """Median CPU [us] per tick of screening the tick's messages, and of building them."""
    from dockhil.runtime.screen import bounds_check

    screens = {t: bounds_check(t) for t in {type(m) for msgs in ticks for m in msgs}}
    builds = {t: rebuilder(t) for t in screens}
    checks = [(screens[type(m)], m) for msgs in ticks for m in msgs]
    makes = [(builds[type(m)], m) for msgs in ticks for m in msgs]
    if not all(screen(m) for screen, m in checks) or any(make(m) != m for make, m in makes):
        raise AssertionError("a recorded message fails its screen or is not rebuilt as it was")

    def median_us(work) -> float:
        runs = []
        for _ in range(repeat):
            c0 = time.process_time()
            for f, m in work:
                f(m)
            runs.append((time.process_time() - c0) / len(ticks) * 1e6)
        return round(statistics.median(runs), 2)

    return {"screen_us_per_tick": median_us(checks), "build_us_per_tick": median_us(makes)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=os.path.join(ROOT, "launch", "hil.yaml"))
    ap.add_argument("--ticks", type=int, default=3000, help="ticks recorded (default 3000)")
    args = ap.parse_args()
    ticks = messages_of(args.scene, args.ticks)
    print(
        json.dumps(
            {
                "scene": os.path.relpath(args.scene, ROOT),
                "ticks": args.ticks,
                "messages_per_tick": round(sum(map(len, ticks)) / len(ticks), 2),
                **cost_us_per_tick(ticks),
            }
        )
    )


if __name__ == "__main__":
    main()

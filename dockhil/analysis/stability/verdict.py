"""One verdict on a scene's loop, for `dockhil calibrate`, `dockhil stability --scene` and the launch's scene
check alike: the loop as the scene places each force (what acts on the simulated state, direct: k_d, b_d;
what acts through the robot's delay: k_h, b_h), the delay h the loop has (its delay end to end and the
servo's lag, which counts as delay), judged by the rightmost root of

    m s^2 + b_d s + k_d + (k_h + b_h s) e^(-s h) = 0,

and said in one line, the same words wherever it is printed."""

from __future__ import annotations


def loop_verdict(m: float, kd: float, bd: float, kh: float, bh: float, h: float) -> dict:
    """{stable, growth_rate_1_s, h_s, line} of the hybrid loop (dockhil.contact.hybrid_stability)."""
    from dockhil.contact.hybrid_stability import hybrid_rightmost

    root = hybrid_rightmost(m, kd, bd, kh, bh, h)
    growth = float(root.real)
    stable = growth < 0.0
    line = (
        f"the loop as the scene places its forces (m {m:.6g} kg; on the simulated state k_d {kd:.6g} N/m, "
        f"b_d {bd:.6g} N s/m; behind the robot's delay k_h {kh:.6g} N/m, b_h {bh:.6g} N s/m; h {h * 1e3:.4g} ms) "
        f"is {'stable' if stable else 'UNSTABLE'}: growth {growth:+.4g} 1/s"
    )
    return {
        "m_kg": m,
        "k_direct_N_per_m": kd,
        "b_direct_Ns_per_m": bd,
        "k_delayed_N_per_m": kh,
        "b_delayed_Ns_per_m": bh,
        "h_s": h,
        "growth_rate_1_s": growth,
        "stable": stable,
        "line": line,
    }


def largest_stable(judge, start: float, most: float = 1e7) -> float | None:
    """The largest x > 0 below which `judge(x)` (True: stable) holds, by doubling then bisection from
    `start` (a stiffness), to 0.1 %; None when even start / 1000 is unstable, `most` when nothing up to it is."""
    lo = start
    while not judge(lo):
        lo /= 2.0
        if lo < start / 1000.0:
            return None
    hi = lo * 2.0
    while judge(hi):
        lo, hi = hi, hi * 2.0
        if hi > most:
            return most
    while hi - lo > 1e-3 * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if judge(mid) else (lo, mid)
    return lo

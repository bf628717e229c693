"""Before a scene runs: the discrete-time loop it will actually run, and whether its step
resolves the contact.

Read from the graph's parameters: the dynamics' masses, integrator and sub-steps, the virtual
impedance (direct: it acts on the state of the same tick), the passive compliance behind the
robot's delay in ticks and servo lag, the tick. From them `dockhil.contact.sampled` gives the
loop's exact eigenvalues; `dockhil.contact.stability` the delay equation the loop stands for.

A run is refused (one line, naming the numbers and the `rate:=` that would work) when
  * the step does not resolve the contact: omega*dt > 0.25 or fewer than 10 samples per contact
    (per oscillation period for a lasting contact), where omega is the contact's fastest pole;
  * the sampled loop and the delay equation disagree on stability (the sampling made it); the
    equation counts the servo lag as delay, and near the margin the sampling is blamed only when
    the equation without the lag disagrees too.
`allow_coarse:=true` runs it anyway, with the refusal as a warning. A resolved but coarse step
(omega*dt > 0.025 or fewer than 100 samples: about 1 % peak-force error) is a warning, and so
is a loop that is unstable as the delay equation predicts (Fig. 11 is such a scene). Warnings
are printed once and land in the summary JSON.
"""

from __future__ import annotations

import cmath
import math

from dockhil.errors import DockhilError
from dockhil.scene.schema import MAX_RATE


def first_node(graph, type_name: str):
    return next((gn for gn in graph.nodes.values() if gn.type_name == type_name), None)


def scene_loop(graph, dt: float | None = None) -> dict | None:
    """The loop of a scene at tick dt (default: the scene's): SampledLoop, the delay h [s], the
    target contact (m, k, b) and its span (contact duration or period); None without dynamics."""
    dyn = first_node(graph, "satellite_dynamics")
    if dyn is None:  # no loop to check: nothing of the science (numpy) is loaded
        return None
    from dockhil.contact import sampled
    from dockhil.contact.hilloop import delay_ticks

    p = dyn.params
    dt = graph.scene.dt if dt is None else dt
    m1, m2 = p["m1"], p["m2"]
    m = m1 if m2 == 0.0 else m1 * m2 / (m1 + m2)
    common = dict(dt=dt, method=p["method"], substeps=p.get("substeps", 1))
    free = p["thrust"] == 0.0 and m2 > 0.0 and p["v1"] > p["v2"]
    if p["model"] == "ideal":
        loop = sampled.SampledLoop(m, p["kcs"], p["bcs"], held=False, **common)
        return _with_target(
            dict(loop=loop, h=0.0, delay_known=True, m=m, kd=p["kcs"], bd=p["bcs"], kh=0.0, bh=0.0),
            p,
            free,
            p["kcs"],
            p["bcs"],
        )
    imp, ft = first_node(graph, "virtual_impedance"), first_node(graph, "ft_sim")
    k1 = b1 = k2 = b2 = 0.0
    kcs = bcs = None
    passive = ft.params["k"] if ft is not None else None
    if imp is not None:
        ip = imp.params
        if ip["mode"] == "determine" and m2 > 0.0:
            from dockhil.contact.impedance import impedance_closed_form
            from dockhil.contact.scenario import ContactScenario

            kcs, bcs = ip["kcs"], ip["bcs"]
            if ip.get("contact") == "hunt_crossley":
                from dockhil.contact.comploop import linear_equivalent

                kcs, bcs = linear_equivalent(ip, m)
            i = impedance_closed_form(ContactScenario(m1, m2, kcs, bcs, ip["k"], 0.03, 0.0), warn=False)
            k1, b1, k2, b2 = i.k1, i.b1, i.k2, i.b2
        else:
            k1, b1, k2, b2 = ip["k1"], ip["b1"], ip["k2"], ip["b2"]
        passive = ip["k"] if passive is None else passive  # real sensor: the compliance the scene names
    # Relative acceleration of the virtual forces: -(m2^2 k1 + m1^2 k2) / M^2 p / m (see hybrid.virtual_forces).
    if m2 == 0.0:
        kd, bd = k1, b1
    else:
        w1, w2 = (m2 / (m1 + m2)) ** 2, (m1 / (m1 + m2)) ** 2
        kd, bd = w1 * k1 + w2 * k2, w1 * b1 + w2 * b2
    kh = passive or 0.0
    delay = first_node(graph, "delay_injector")
    robot = first_node(graph, "robot_sim")
    h = delay.params["delay"] if delay is not None else 0.0
    if robot is not None and robot.params.get("delay", 0.0) > 0.0:  # a simulated robot that delays the command itself
        h += robot.params["delay"] * robot.params.get("delay_scale", 1.0)
    if ft is not None:  # the simulated hardware's truth: its sensor's own delay, its true stiffness
        h += ft.params.get("delay", 0.0)
        kh *= ft.params.get("k_scale", 1.0)
    lag = robot.params["lag"] if robot is not None else 0.0
    # A robot driver's delay is the hardware's, which no parameter of the scene gives; a loop file's
    # (loop:=, dockhil calibrate's) is the identified one: its delay end to end and its lag.
    hardware = any(gn.cls.moves_hardware for gn in graph.nodes.values())
    values = getattr(graph.scene, "values", {}) or {}
    measured = hardware and delay is None and bool(values.get("loop")) and "delay" in values
    if measured:
        h, lag = float(values["delay"]), float(values.get("lag", 0.0))
    if delay_ticks(h, dt) > sampled.MAX_DELAY_TICKS:
        raise DockhilError(
            f"{graph.scene.path}: the delay h = {h:g} s at {1.0 / dt:g} Hz is {delay_ticks(h, dt)} "
            f"ticks of delay; the scene check resolves up to {sampled.MAX_DELAY_TICKS} ticks: give a "
            f"shorter delay or a lower rate"
        )
    loop = sampled.SampledLoop(
        m,
        kd,
        bd,
        kh,
        0.0,
        delay_ticks=delay_ticks(h, dt),
        lag=lag,
        **common,
    )
    info = dict(
        loop=loop,
        h=h,
        delay_known=delay is not None or not hardware or measured,
        hardware=hardware,
        m=m,
        kd=kd,
        bd=bd,
        kh=kh,
        bh=0.0,
    )
    if kcs is not None:
        return _with_target(info, p, free, kcs, bcs)
    return _with_target(info, p, False, kd + kh, bd)


def _with_target(info: dict, p: dict, free: bool, k: float, b: float) -> dict:
    from dockhil.contact import sampled
    from dockhil.contact.ideal import contact_duration

    m = info["m"]
    omega = sampled.contact_poles_speed(m, abs(k), abs(b))
    span, name = math.inf, "contact"
    if free:
        span = contact_duration(m, k, b)
    if not math.isfinite(span) or span <= 0.0:
        span, name = (2.0 * math.pi / omega if omega > 0.0 else math.inf), "period"
    info.update(target=(m, k, b), omega=omega, span=span, span_name=name)
    return info


def _reference(info: dict, with_lag: bool = True):
    """The rightmost roots of the delay equation the loop stands for, its robot's servo lag counted
    as delay (1/(1 + tau s) and e^(-s tau) agree to first order, as `dockhil calibrate` counts it):
    the sampled loop has the lag, so a reference without it calls the lag's growth the sampling's."""
    from dockhil.contact.hybrid_stability import hybrid_roots

    loop = info["loop"]
    h = info["h"] + (loop.lag if with_lag else 0.0) if loop.held else 0.0
    return hybrid_roots(info["m"], info["kd"], info["bd"], info["kh"], info["bh"], h, count=4)


def _analyse(info: dict, cont=None) -> dict:
    """Dominant root of the sampled loop, and the delay equation's roots `cont` (computed when not given)."""
    from dockhil.contact import sampled

    loop = info["loop"]
    if cont is None:
        cont = _reference(info)
    try:
        guesses = [cmath.exp(complex(s) * loop.dt) for s in cont] + [
            cmath.exp(complex(s).conjugate() * loop.dt) for s in cont
        ]
        z = sampled.sampled_roots(loop, guesses)[0]
        rho = abs(complex(z))
    except OverflowError:  # a root so far right that exp(s dt) overflows: the sampled loop explodes
        rho = math.inf
    except sampled.RootsNotResolved as exc:
        raise DockhilError(
            f"the scene check cannot judge this loop: {exc}; give a shorter delay or a lower rate"
        ) from None
    return dict(
        continuous=complex(cont[0]),
        roots=cont,
        rho=rho,
        growth=(math.log(rho) / loop.dt) if 0 < rho < math.inf else (math.inf if rho else -math.inf),
    )


def _stable_rate(graph, info: dict, start: float, cont) -> float | None:
    """The lowest rate from `start` up (doubling) whose sampled loop agrees with the delay equation;
    None when none does up to 256 times `start` (the integrator itself is the problem) or up to
    the highest rate a scene runs at."""
    from dockhil.contact import sampled
    from dockhil.contact.hilloop import delay_ticks

    rate = start
    for _ in range(9):
        if rate > MAX_RATE or delay_ticks(info["h"], 1.0 / rate) > sampled.MAX_DELAY_TICKS:
            return None
        trial = scene_loop(graph, 1.0 / rate)
        try:
            a = _analyse(trial, cont)
        except DockhilError:  # a rate this fine makes the delay too many ticks to judge
            return None
        tol = 1e-9 * max(1.0, trial["omega"])
        if (a["growth"] > tol) == (a["continuous"].real > tol):
            return rate
        rate = sampled.round_up(2.0 * rate)
    return None


def sixdof_nodes(graph) -> tuple:
    """The scene's 6-DOF dynamics and virtual-impedance nodes, set up (bodies, start, mount,
    contact); None for one the scene does not have."""
    from dockhil.node import NodeContext

    def made(type_name):
        gn = first_node(graph, type_name)
        if gn is None:
            return None
        node = gn.cls(NodeContext(gn.name, graph.scene.dt, log=lambda m: None), **gn.params)
        node.setup()
        return node

    return made("satellite_dynamics6"), made("virtual_impedance6")


def scene_loop6(graph):
    """The linearised loop (stability6.MultiAxisLoop, its delay h the delay injector's) of a 6-DOF
    scene at its start configuration; None without the 6-DOF dynamics and virtual impedance."""
    dyn, imp = sixdof_nodes(graph)
    if dyn is None or imp is None:
        return None
    from dockhil.contact.impedance6 import body_mobility
    from dockhil.contact.interface6 import InterfaceGeometry
    from dockhil.contact.stability6 import hybrid_loop6

    delay = first_node(graph, "delay_injector")
    h = float(delay.params.get("delay", 0.032)) if delay is not None else 0.0
    g = InterfaceGeometry(dyn.m1, dyn.m2)
    return hybrid_loop6(
        imp.wall.ideal, imp.wall.passive, body_mobility(dyn.m1, g.point, g), body_mobility(dyn.m2, g.point, g), h
    )


SOFTER = "give a softer contact or heavier bodies"


def _too_fast(rate: float) -> str:
    """The advice for a contact only a rate above what a scene runs at would resolve."""
    return f"resolving it needs a rate of {rate:g} Hz, above the {MAX_RATE:g} Hz a scene runs at: {SOFTER}"


def _coarse(res, good: float) -> str:
    """The warning of a resolved but coarse step."""
    return (
        f"coarse step: {res.describe()}; the peak force errs by about {40 * res.omega_dt:.2g} %; "
        f"rate:={good:g} resolves it"
    )


def _check6(graph, loop, refuse: bool) -> dict:
    """A 6-DOF scene's step against its contact: the fastest pole of M s^2 + B s + K with the
    whole contact (virtual and passive, undelayed) at the start configuration, judged as the
    1-DOF check judges its contact (per oscillation period)."""
    import numpy as np

    from dockhil.contact import sampled

    n = loop.n
    m_inv = np.linalg.inv(loop.mass)
    k, b = loop.k_direct + loop.k_delayed, loop.b_direct + loop.b_delayed
    poles = np.linalg.eigvals(np.block([[np.zeros((n, n)), np.eye(n)], [-m_inv @ k, -m_inv @ b]]))
    omega = float(np.max(np.abs(poles)))
    if omega == 0.0:
        return {"loop": {}, "warnings": []}
    dt = graph.scene.dt
    res = sampled.Resolution(omega, dt, 2.0 * math.pi / omega, "period")
    numbers = {
        "rate_Hz": 1.0 / dt,
        "omega_rad_s": omega,
        "omega_dt": res.omega_dt,
        "samples_per_period": res.samples,
        "suggested_rate_Hz": None,
    }
    warnings = []
    if res.refused or res.coarse:
        good = numbers["suggested_rate_Hz"] = res.fine_rate()
        if res.refused:
            fix = f"run with rate:={good:g}" if good <= MAX_RATE else _too_fast(good)
            line = f"the step does not resolve the contact: {res.describe()}; {fix}"
            if refuse:
                raise DockhilError(f"{graph.scene.path}: refused: {line}")
            warnings.append(f"not resolved: {line}")
        else:
            warnings.append(_coarse(res, good))
    # The delayed loop as the 1-DOF check judges it (a warning: Fig. 11's scenes are unstable on
    # purpose): the rightmost root of det(M s^2 + B s + K_direct + K_delayed e^{-sh}), about 0.1 s.
    from dockhil.contact import stability6

    root = stability6.rightmost(loop)
    numbers["rightmost_root_1_s"], numbers["rightmost_axis"] = [root.s.real, root.s.imag], root.axis
    if root.s.real > 1e-9 * max(1.0, omega):
        warnings.append(
            f"the loop is unstable: linearised at the start, the delayed loop grows at "
            f"{root.s.real:+.4g} 1/s (rightmost root {root.s.real:+.4g} {root.s.imag:+.4g}j, led by axis "
            f"{root.axis}); `dockhil stability multi --scene` on it gives the stable stiffness"
        )
    return {"loop": numbers, "warnings": warnings}


def scene_check(graph, refuse: bool = True) -> dict:
    """{"loop": numbers, "warnings": [one line each]}; raises DockhilError (one line) when the
    scene must not run (and `refuse`), unless the dynamics' allow_coarse is set."""
    info = scene_loop(graph)
    if info is None:
        loop6 = scene_loop6(graph)
        check = {"loop": {}, "warnings": []} if loop6 is None else _check6(graph, loop6, refuse)
        check["warnings"] += body_mismatches(graph)
        return check
    from dockhil.contact import sampled

    loop = info["loop"]
    res = sampled.Resolution(info["omega"], loop.dt, info["span"], info["span_name"])
    try:
        a = _analyse(info)
    except DockhilError as exc:
        raise DockhilError(f"{graph.scene.path}: {exc}") from None
    cont, rho, growth = a["continuous"], a["rho"], a["growth"]
    rate = 1.0 / loop.dt
    numbers = {
        "rate_Hz": rate,
        "omega_rad_s": res.omega,
        "omega_dt": res.omega_dt,
        f"samples_per_{res.span_name}": res.samples if math.isfinite(res.samples) else None,
        "delay_ticks": loop.delay_ticks,
        "spectral_radius": rho,
        "sampled_growth_rate_1_s": growth if math.isfinite(growth) else None,
        "continuous_growth_rate_1_s": cont.real,
    }
    if not info["delay_known"]:
        numbers["note"] = "the robot's delay is the hardware's: the loop is analysed without it"
    problems = []
    if res.refused:
        problems.append(f"the step does not resolve the contact: {res.describe()}")
    # Marginal loops (an undamped ideal contact, exact: |z| = 1 to rounding) count as not growing.
    tol = 1e-9 * max(1.0, res.omega)
    sampled_unstable, physics_unstable = growth > tol, cont.real > tol
    # The lag only approximately a delay: the sampling is blamed only where the reference without the
    # lag disagrees too (a lagged loop's stability lies between the two near the margin).
    if sampled_unstable != physics_unstable and loop.held and loop.lag > 0.0:
        physics_unstable = complex(_reference(info, with_lag=False)[0]).real > tol
    if sampled_unstable != physics_unstable:
        problems.append(
            f"the sampled loop {'grows' if sampled_unstable else 'does not grow'} (spectral radius {rho:.9g}, "
            f"{growth:+.4g} 1/s) while the delay equation it stands for "
            f"{'grows' if physics_unstable else 'does not'} (rightmost root {cont.real + 0.0:+.4g} 1/s)"
        )
    warnings = []
    dyn = first_node(graph, "satellite_dynamics")
    allowed = bool(dyn.params.get("allow_coarse", False))
    if problems:
        start = max(rate, res.fine_rate())
        good = _stable_rate(graph, info, start, a["roots"])
        numbers["suggested_rate_Hz"] = good
        if good is not None:
            line = f"{'; '.join(problems)}; run with rate:={good:g}"
        elif start > MAX_RATE:
            line = f"{'; '.join(problems)}; {_too_fast(start)}"
        else:
            fix = SOFTER if loop.method == "exact" else "use method:=exact"
            line = (
                f"{'; '.join(problems)}; no rate up to {min(256 * start, MAX_RATE):g} Hz fixes it with method "
                f"{loop.method!r}: {fix}"
            )
        if refuse and not allowed:
            raise DockhilError(f"{graph.scene.path}: refused: {line} (or allow_coarse:=true to run anyway)")
        warnings.append(f"ran although not resolved (allow_coarse): {line}")
    elif res.coarse:
        good = res.fine_rate()
        numbers["suggested_rate_Hz"] = good
        warnings.append(_coarse(res, good))
    h = info["h"]
    if loop.held and h > 0.0 and abs(loop.delay_ticks * loop.dt - h) > 1e-9 * h:
        warnings.append(
            f"the delay h = {h:g} s runs as {loop.delay_ticks} ticks = {loop.delay_ticks * loop.dt:g} s "
            f"at {rate:g} Hz (choose a rate with a whole number of ticks in h)"
        )
    if info["delay_known"] and loop.held:
        from dockhil.analysis.stability.verdict import loop_verdict

        verdict = loop_verdict(info["m"], info["kd"], info["bd"], info["kh"], info["bh"], h + loop.lag)
        numbers["verdict"] = verdict["line"]
        values = getattr(graph.scene, "values", {}) or {}
        if not verdict["stable"] and info.get("hardware") and refuse and not values.get("allow_unstable"):
            # a robot would run it: a contact that grows is not started on hardware without being asked to
            raise DockhilError(
                f"{graph.scene.path}: refused: {verdict['line']}; a robot would run it: give a stable loop "
                f"(a softer kcs or more bcs), or allow_unstable:=true to run it anyway"
            )
    if physics_unstable and sampled_unstable:
        warnings.append(
            f"the loop is unstable: it grows at {growth:+.4g} 1/s (spectral radius {rho:.6g}), as "
            f"the delay equation predicts ({cont.real:+.4g} 1/s)"
            + (f"; {numbers['verdict']}" if "verdict" in numbers else "")
        )
    return {"loop": numbers, "warnings": warnings + body_mismatches(graph)}


BODY_PARAMS = (
    "m1",
    "m2",
    "inertia1",
    "inertia2",
    "interface1",
    "interface2",
    "interface_orientation1",
    "interface_orientation2",
)


def body_mismatches(graph) -> list[str]:
    """One warning per body parameter that the virtual impedance and the dynamics both take and
    are given differently: the impedance is then tuned for other bodies than those that fly (its
    closed form, its wall split, its mobilities), so the loop does not make the contact it is
    meant to reproduce. A warning, not a refusal: a mistuned impedance can be the experiment."""
    dyn = first_node(graph, "satellite_dynamics") or first_node(graph, "satellite_dynamics6")
    imp = first_node(graph, "virtual_impedance") or first_node(graph, "virtual_impedance6")
    if dyn is None or imp is None:
        return []

    def said(gn, name):
        unit = getattr(gn.cls.params.get(name), "unit", "")
        return f"{name} = {gn.params[name]!r}{' ' + unit if unit else ''}"

    return [
        f"node {imp.name!r} is tuned for {said(imp, name)} but node {dyn.name!r} integrates {said(dyn, name)}: "
        f"the virtual impedance does not make the ideal contact for these bodies; give both the same {name}"
        for name in BODY_PARAMS
        if name in imp.params and name in dyn.params and imp.params[name] != dyn.params[name]
    ]

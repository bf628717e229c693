"""The five simulation nodes, each stepped alone with dockhil.testing.NodeHarness.

Expected values come from closed forms written here: a body under constant
force, the CoM-frame virtual impedance (NOTES: k1 = (kcs - k)(1 + m1/m2), ...),
Hooke's law on the passive compliance, a first-order lag, a shift by
round(delay/dt) ticks, the damped oscillator of the ideal contact."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from dockhil.errors import ParamError
from dockhil.testing import NodeHarness, body_wrenches, robot_command, robot_state, satellite_state, wrench

DT = 0.001


def chaser(out):
    b = out["state"].bodies[0]
    return b.pose.position.x, b.twist.linear.x


def target(out):
    b = out["state"].bodies[1]
    return b.pose.position.x, b.twist.linear.x


# -- satellite_dynamics ------------------------------------------------------------------


# x after n steps of dt under constant acceleration a, v0 = 0: exact (and RK4, exact for a
# quadratic) a t^2/2; semi-implicit Euler a dt^2 n(n+1)/2; explicit Euler a dt^2 n(n-1)/2.
DRIFT = {
    "exact": lambda n: n * n / 2,
    "rk4": lambda n: n * n / 2,
    "symplectic_euler": lambda n: n * (n + 1) / 2,
    "euler": lambda n: n * (n - 1) / 2,
}


@pytest.mark.parametrize("method", sorted(DRIFT))
def test_dynamics_free_body_under_constant_force_follows_x_v_t_plus_f_t2_over_2m(method):
    m1, m2, v1, force = 750.0, 1e6, 0.03, 12.0
    with NodeHarness("satellite_dynamics", dt=DT, m1=m1, m2=m2, v1=v1, x1=-0.5, method=method) as h:
        outs = h.run(400, inputs={"ft": wrench(fx=force)})
    # The force published at tick k acts from tick k to k+1 (the input is not feedthrough):
    # from tick 0 on it acts all the time, so tick k is t = k dt under constant force.
    for k in (0, 1, 10, 399):
        t = k * DT
        x1, u1 = chaser(outs[k])
        x2, u2 = target(outs[k])
        assert x1 == pytest.approx(-0.5 + v1 * t + force / m1 * DT * DT * DRIFT[method](k), abs=1e-12)
        assert u1 == pytest.approx(v1 + force * t / m1, abs=1e-12)
        assert x2 == pytest.approx(-force / m2 * DT * DT * DRIFT[method](k), abs=1e-12)  # the opposite force
        assert u2 == pytest.approx(-force * t / m2, abs=1e-15)


def test_dynamics_reads_the_sensor_one_tick_late_and_sums_thrust_sensor_and_impedance():
    m1, m2, thrust, fs, fv1, fv2 = 500.0, 2000.0, 3.0, -4.0, 1.5, 2.5
    with NodeHarness("satellite_dynamics", dt=DT, m1=m1, m2=m2, v1=0.0, thrust=thrust) as h:
        for _ in range(5):
            h.step()  # thrust alone
        out5 = h.step(inputs={"ft": wrench(fx=fs), "impedance": body_wrenches(fv1, fv2)})  # tick 5
        out6 = h.step()  # tick 6: the tick-5 inputs act from 5 to 6
        out7 = h.step()  # tick 7: nothing published at tick 6: thrust alone again
    assert chaser(out5)[1] == pytest.approx(5 * thrust * DT / m1, abs=1e-15)  # not yet affected
    assert target(out5)[1] == 0.0
    assert chaser(out6)[1] == pytest.approx((6 * thrust + fs + fv1) * DT / m1, abs=1e-15)
    assert target(out6)[1] == pytest.approx((-fs + fv2) * DT / m2, abs=1e-15)
    assert chaser(out7)[1] == pytest.approx((7 * thrust + fs + fv1) * DT / m1, abs=1e-15)
    assert target(out7)[1] == pytest.approx(target(out6)[1], abs=1e-18)


def test_dynamics_conserves_momentum_under_the_measured_force_and_commands_the_relative_pose():
    m1, m2 = 750.0, 1200.0
    rng = np.random.default_rng(3)
    forces = rng.normal(0.0, 20.0, 300)
    with NodeHarness("satellite_dynamics", dt=DT, m1=m1, m2=m2, v1=0.02, v2=-0.01, x2=0.001) as h:
        outs = h.run(300, inputs=lambda k: {"ft": wrench(fx=forces[k])})
    p0 = m1 * 0.02 + m2 * -0.01
    for out in outs:
        (x1, u1), (x2, u2) = chaser(out), target(out)
        assert m1 * u1 + m2 * u2 == pytest.approx(p0, abs=1e-12)  # internal forces only
        cmd = out["command"]
        assert cmd.pose.position.x == x1 - x2 and cmd.twist.linear.x == u1 - u2
        assert cmd.header.frame == "target" and out["state"].header.frame == "world"


def test_dynamics_command_waits_at_max_gap_while_the_bodies_are_farther_apart():
    # The chaser flies away from a fixed target at 0.1 m/s from 0.05 m apart, then is pushed back:
    # the command follows the gap to 0.2 m, stays there, still, and follows again once under it.
    with NodeHarness("satellite_dynamics", dt=DT, m1=1.0, m2=0.0, x1=-0.05, v1=-0.1, max_gap=0.2) as h:
        away = h.run(3000)
        back = h.run(3000, inputs={"ft": wrench(fx=0.2)})
    for out in away + back:
        x1, u1 = chaser(out)
        cmd = out["command"]
        if x1 >= -0.2:
            assert (cmd.pose.position.x, cmd.twist.linear.x) == (x1, u1)
        else:
            assert (cmd.pose.position.x, cmd.twist.linear.x) == (-0.2, 0.0)
    assert chaser(away[-1])[0] < -0.3 and chaser(back[-1])[0] > -0.2  # it went past, and came back in
    assert any(m.startswith("bodies ") and "waits at the gap max_gap = 0.2 m" in m for m in h.logs)


def test_dynamics_fixed_target_stays_put():
    with NodeHarness("satellite_dynamics", dt=DT, m1=100.0, m2=0.0, x1=0.2, x2=0.25, v1=0.0) as h:
        outs = h.run(100, inputs={"ft": wrench(fx=-2.0)})
    t = 99 * DT
    assert chaser(outs[-1])[0] == pytest.approx(0.2 - 2.0 * t * t / 200.0, abs=1e-12)
    assert target(outs[-1]) == (0.25, 0.0)


def test_dynamics_ideal_model_is_the_damped_oscillator_while_in_contact():
    m1, m2, kcs, bcs, v0 = 750.0, 1e6, 3000.0, 40.0, 0.03
    m = m1 * m2 / (m1 + m2)
    wn = math.sqrt(kcs / m)
    zeta = bcs / (2 * m * wn)
    wd = wn * math.sqrt(1 - zeta * zeta)
    with NodeHarness("satellite_dynamics", dt=DT, model="ideal", m1=m1, m2=m2, kcs=kcs, bcs=bcs, v1=v0) as h:
        assert h.input_ports == {}  # the ideal scene needs no sensor and no impedance
        outs = h.run(1800)
    t_sep = math.pi / wd  # the spring-dashpot's penetration returns to zero
    for k in range(0, int(t_sep / DT) - 5, 25):
        t = k * DT
        (x1, u1), (x2, u2) = chaser(outs[k]), target(outs[k])
        assert x1 - x2 == pytest.approx(v0 / wd * math.exp(-zeta * wn * t) * math.sin(wd * t), abs=1e-9)
        assert outs[k]["state"].in_contact  # from t = 0: at the surface and closing in
        assert m1 * u1 + m2 * u2 == pytest.approx(m1 * v0, abs=1e-9)
    # After the contact: apart, flying apart at a constant speed, never to touch again.
    after = [chaser(o)[1] - target(o)[1] for o in outs[int(t_sep / DT) + 20 :]]
    assert not outs[-1]["state"].in_contact
    assert max(after) < 0 and max(after) - min(after) < 1e-12
    assert -after[-1] < v0  # the dashpot took energy


def test_dynamics_in_wall_time_holds_the_start_pose_until_the_sensor_answers():
    with NodeHarness("satellite_dynamics", dt=DT, sim_time=False, x1=-0.01, v1=0.03) as h:
        first = h.run(3)
        assert all(set(o) == {"command"} for o in first)  # no state: the run has not begun
        assert all(o["command"].pose.position.x == -0.01 for o in first)
        h.step(inputs={"ft": wrench()})  # tick 3: the sensor answers; dynamics read it at tick 4
        assert set(h.step()) == {"state", "command"}


def test_dynamics_refuses_bad_parameters_with_one_line():
    with pytest.raises(ParamError, match=r"parameter 'm1': 0.0 is out of range, must be > 0.0"):
        NodeHarness("satellite_dynamics", m1=0.0)
    with pytest.raises(ParamError, match=r"parameter 'method': 'leapfrog' is not one of exact"):
        NodeHarness("satellite_dynamics", method="leapfrog")


# -- virtual_impedance ---------------------------------------------------------------------


def closed_form(m1, m2, kcs, bcs, k):
    """NOTES: the CoM-frame closed form of the virtual impedance."""
    return ((kcs - k) * (1 + m1 / m2), bcs * (1 + m1 / m2), (kcs - k) * (1 + m2 / m1), bcs * (1 + m2 / m1))


@pytest.mark.parametrize(
    "m1, m2, kcs, bcs, k", [(750.0, 1e6, 3000.0, 40.0, 1000.0), (300.0, 900.0, 5000.0, 12.0, 800.0)]
)
def test_impedance_is_the_spring_damper_to_the_wall_moving_at_v_com(m1, m2, kcs, bcs, k):
    k1, b1, k2, b2 = closed_form(m1, m2, kcs, bcs, k)
    v1, v2, t = 0.03, -0.002, 0.21
    V = (m1 * v1 + m2 * v2) / (m1 + m2)
    with NodeHarness("virtual_impedance", dt=DT, m1=m1, m2=m2, kcs=kcs, bcs=bcs, k=k) as h:
        assert f"k1={k1:.6g} N/m" in h.logs[0] and f"b2={b2:.6g} N s/m" in h.logs[0]
        for pen in (0.004, 0.0005):
            # A state whose centre of mass is on the wall at V t, the probe `pen` into the target.
            x1 = V * t + m2 / (m1 + m2) * pen
            x2 = V * t - m1 / (m1 + m2) * pen
            out = h.step(inputs={"state": satellite_state(x1, v1, x2, v2, m1, m2)})  # feedthrough: this tick
            f1, f2 = (w.force.x for w in out["wrench"].wrenches)
            assert f1 == pytest.approx(-k1 * (x1 - V * t) - b1 * (v1 - V), rel=1e-9)
            assert f2 == pytest.approx(-k2 * (x2 - V * t) - b2 * (v2 - V), rel=1e-9)
        out = h.step(inputs={"state": satellite_state(-0.001, v1, 0.0, v2, m1, m2)})  # apart
        assert [w.force.x for w in out["wrench"].wrenches] == [0.0, 0.0]
        assert [w.force.x for w in h.step()["wrench"].wrenches] == [0.0, 0.0]  # no state yet: no force


def test_impedance_table_1_values_and_the_negative_stiffness_warning():
    with NodeHarness("virtual_impedance") as h:  # Table 1 defaults
        imp = h.node.impedance
    assert (imp.k1, imp.b1) == pytest.approx((2001.5, 40.03), rel=1e-12)
    assert (imp.k2, imp.b2) == pytest.approx((2668700, 53373), rel=2e-5)  # as printed, rounded
    with warnings.catch_warnings(record=True) as escaped:
        warnings.simplefilter("always")
        with NodeHarness("virtual_impedance", kcs=500.0, k=1000.0) as h:
            assert h.node.impedance.k1 == pytest.approx((500.0 - 1000.0) * (1 + 750.0 / 1e6))
    assert [line for line in h.logs if line.startswith("warning:")], h.logs  # one log line says it
    # ... and only the log line: a Python warning would add its own lines to the node's stderr.
    assert [str(w.message) for w in escaped] == []


def test_impedance_given_on_a_fixed_target_pulls_on_the_chaser_alone():
    with NodeHarness("virtual_impedance", mode="given", m2=0.0, k1=100.0, b1=7.0, k2=5.0, b2=5.0) as h:
        out = h.step(inputs={"state": satellite_state(0.3 + 0.002, 0.01, 0.3, 0.0, 750.0, 0.0)})
    f1, f2 = (w.force.x for w in out["wrench"].wrenches)
    assert f1 == pytest.approx(-(100.0 * 0.002 + 7.0 * 0.01)) and f2 == 0.0


def test_impedance_determine_needs_a_free_target():
    h = NodeHarness("virtual_impedance", m2=0.0)
    with pytest.raises(ParamError, match="mode 'determine' needs a free target"):
        h.setup()


# -- ft_sim ---------------------------------------------------------------------------------


def test_ft_sim_is_hookes_law_on_the_penetration_and_never_pulls():
    with NodeHarness("ft_sim", k=1000.0) as h:
        forces = [h.step(inputs={"robot": robot_state(x)})["wrench"].wrench.force.x for x in (0.012, 0.0, -0.02)]
        none = h.step()["wrench"].wrench.force.x  # no pose reported: no force
    assert forces == [pytest.approx(-12.0), 0.0, 0.0] and none == 0.0


def test_ft_sim_bias_quantization_and_seeded_noise():
    with NodeHarness("ft_sim", k=1000.0, bias=0.3, quantization=0.25) as h:
        assert h.step(inputs={"robot": robot_state(0.0071)})["wrench"].wrench.force.x == -6.75  # -7.1 + 0.3

    def noisy(seed):
        with NodeHarness("ft_sim", noise=0.5, seed=seed) as h:
            return np.array([o["wrench"].wrench.force.x for o in h.run(4000, {"robot": robot_state(-1.0)})])

    a, b, c = noisy(1), noisy(1), noisy(2)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert abs(a.mean()) < 0.05 and a.std() == pytest.approx(0.5, rel=0.05)


def test_ft_sim_holds_each_sample_for_one_period_of_its_rate():
    with NodeHarness("ft_sim", k=100.0, rate=100.0) as h:  # a sample every 10 ticks of 1 ms
        outs = h.run(35, inputs=lambda k: {"robot": robot_state(0.001 * (k + 1))})
    for k, out in enumerate(outs):
        sampled = 10 * (k // 10)
        assert out["wrench"].wrench.force.x == pytest.approx(-100.0 * 0.001 * (sampled + 1))


# -- robot_sim --------------------------------------------------------------------------------


def test_robot_sim_follows_exactly_without_lag_and_reports_nothing_before_a_command():
    with NodeHarness("robot_sim") as h:
        assert h.step() == {}
        out = h.step(inputs={"command": robot_command(0.004, 0.03)})
    s = out["state"]
    assert (s.pose.position.x, s.twist.linear.x) == (0.004, 0.03) and s.header.tick == 1


def test_robot_sim_lag_is_a_first_order_step_response():
    tau = 0.02
    with NodeHarness("robot_sim", lag=tau) as h:
        h.step(inputs={"command": robot_command(0.0)})  # the first command places the servo
        outs = h.run(100, inputs={"command": robot_command(0.005)})
    for n in (1, 10, 50, 100):
        assert outs[n - 1]["state"].pose.position.x == pytest.approx(0.005 * (1 - math.exp(-n * DT / tau)), rel=1e-9)


# -- delay_injector -------------------------------------------------------------------------------


@pytest.mark.parametrize("delay, dt", [(0.032, 0.001), (0.016, 0.002), (0.0113, 0.001), (0.0, 0.001)])
def test_delay_injector_shifts_by_round_delay_over_dt_ticks(delay, dt):
    n = int(math.floor(delay / dt + 0.5))  # round half up; none of these is a tie
    with NodeHarness("delay_injector", dt=dt, delay=delay) as h:
        outs = h.run(n + 20, inputs=lambda k: {"input": robot_command(x=0.001 * k)})
    assert all(o == {} for o in outs[:n])  # nothing to deliver before the delay has passed
    for k in range(n, n + 20):
        out = outs[k]["output"]
        assert out.pose.position.x == pytest.approx(0.001 * (k - n))
        assert out.header.tick == k and out.header.frame == "target"  # restamped, frame kept


def test_delay_injector_jitter_stays_within_its_bound_and_never_reorders():
    d, j = 0.010, 0.005
    with NodeHarness(
        "delay_injector", delay=d, jitter=j, seed=4, type="dockhil/WrenchStamped", input="/ft/wrench", output="/ft/late"
    ) as h:
        outs = h.run(500, inputs=lambda k: {"input": wrench(fx=float(k))})
    sent = [(k, int(o["output"].wrench.force.x)) for k, o in enumerate(outs) if o]
    ages = [k - src for k, src in sent]
    assert min(ages) >= 10 and max(ages) <= 15 and len(set(ages)) > 3
    assert all(b[1] >= a[1] for a, b in zip(sent, sent[1:]))


def test_delay_injector_loss_repeats_the_last_message_at_about_the_loss_rate():
    with NodeHarness("delay_injector", delay=0.002, loss=0.3, seed=9) as h:
        outs = h.run(3000, inputs=lambda k: {"input": robot_command(x=1e-6 * k)})
    xs = [o["output"].pose.position.x for o in outs[2:]]
    repeats = sum(a == b for a, b in zip(xs, xs[1:])) / (len(xs) - 1)
    assert repeats == pytest.approx(0.3, abs=0.04)
    assert all(b >= a for a, b in zip(xs, xs[1:]))  # held, never older

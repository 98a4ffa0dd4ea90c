"""Traffic (sources/traffic.py): the Intelligent Driver Model's closed forms, a stop wave that
reaches standstill and starts again, no collisions, a smooth lane change, oncoming traffic, and
the same paths for the same seed.

Closed forms written out here from Treiber, Hennecke and Helbing (2000), Eq. 2-3, not taken from
the module: free road a (1 - (v/v0)^delta); equilibrium gap s_e(v) = (s0 + v T) / sqrt(1 -
(v/v0)^delta), where the acceleration is zero; a standing queue's gap s_e(0) = s0.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.sources.traffic import (Agent, IdmParams, TrafficSpec, idm_accel, min_jerk, simulate,
                                          traffic_motions)

P = IdmParams(v0=33.33, T=1.6, s0=2.0, a=0.73, b=1.67, delta=4.0)   # Treiber et al. 2000, Table I


@pytest.mark.parametrize("v", [0.0, 5.0, 20.0, 33.0])
def test_free_road_acceleration_is_the_closed_form(v):
    want = 0.73 * (1.0 - (v / 33.33) ** 4)
    assert float(idm_accel(v, math.inf, 0.0, P)) == pytest.approx(want, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("v", [0.5, 5.0, 15.0, 30.0])
def test_equilibrium_gap_gives_zero_acceleration(v):
    gap = (2.0 + v * 1.6) / math.sqrt(1.0 - (v / 33.33) ** 4)
    assert abs(float(idm_accel(v, gap, 0.0, P))) < 1e-12
    # 10 % closer brakes, 10 % farther accelerates (the equilibrium is where the sign changes)
    assert float(idm_accel(v, 0.9 * gap, 0.0, P)) < 0 < float(idm_accel(v, 1.1 * gap, 0.0, P))


def _queue(**kw):
    """Five cars 8 m/s toward a stop line at 60 m, 15 m apart, released at 25 s."""
    spec = TrafficSpec(speed_spread=0.0, stop_line_m=60.0, release_s=25.0, step_s=0.05, **kw)
    agents = [Agent(f"c{k}", 1, 4.77, 40.0 - 15.0 * k, 0.0, 8.0) for k in range(5)]
    return spec, agents, simulate(spec, agents, 60.0)


def test_stop_wave_reaches_standstill_without_collisions_and_restarts():
    spec, agents, r = _queue()
    t = r.times_s
    gaps = r.gaps_m()
    assert np.all(gaps > 0.5), float(np.min(gaps))                     # nobody touches
    before = t < spec.release_s
    for i, a in enumerate(agents):
        assert np.min(r.v[i][before]) < 1e-3                             # every car comes to a stop
        assert r.v[i][-1] > 5.0                                          # ... and drives on after the release
        assert np.all(r.v[i] >= 0)
    # the stop wave runs backwards: each car stops after the one ahead of it
    stops = [t[np.argmax((r.v[i] < 0.01) & before)] for i in range(5)]
    assert all(b > a for a, b in zip(stops, stops[1:])), stops
    # standing queue (just before the release): every gap at or just below s_e(0) = s0 = 2 m, the
    # first car's to the stop line too. The IDM closes on a standing leader asymptotically in s*
    # but its speed reaches zero a little inside s0 (the approach term v dv / (2 sqrt(a b))
    # vanishes with v): at standstill a gap below s0 gives a negative acceleration held at v = 0,
    # so the queue stands; 10 % of s0 bounds that undershoot (1.90-1.93 m here, the same at
    # dt = 0.002 s: the model's, not the integrator's)
    k = np.searchsorted(t, spec.release_s - 0.1)
    assert np.all(r.v[:, k] == 0)
    stand = np.array([60.0 - (r.s[0, k] + 4.77), *gaps[1:, k]])
    assert np.all((stand > 0.9 * 2.0) & (stand <= 2.0)), stand
    # the start wave: each car moves off after the one ahead of it
    go = [t[np.argmax((t > spec.release_s) & (r.v[i] > 0.5))] for i in range(5)]
    assert all(b > a for a, b in zip(go, go[1:])), go


def test_same_seed_same_paths_other_seed_other_speeds():
    agents = [Agent("a", 1, 4.77, 0.0, 0.0, 10.0), Agent("b", -1, 4.49, -200.0, 3.5, 12.0)]
    runs = [simulate(TrafficSpec(seed=s, speed_spread=0.1), agents, 5.0) for s in (3, 3, 4)]
    np.testing.assert_array_equal(runs[0].s, runs[1].s)
    assert runs[0].params[0].v0 != runs[2].params[0].v0
    assert not np.array_equal(runs[0].s, runs[2].s)


def test_lane_change_follows_the_minimum_jerk_profile_once_safe():
    # the target lane holds a car 1 m behind the changer at first, slower: unsafe; it waits until the gap
    # lets the new follower brake at most b_safe
    spec = TrafficSpec(speed_spread=0.0, lane_change_vehicle="x", lane_change_to_x_m=3.5,
                       lane_change_start_s=0.0, lane_change_duration_s=4.0)
    agents = [Agent("x", 1, 4.77, 20.0, 0.0, 12.0), Agent("f", 1, 4.77, 14.23, 3.5, 10.0)]
    r = simulate(spec, agents, 12.0)
    t0 = r.lane_change_start_s
    assert t0 is not None and t0 > 0.0
    i = r.index("x")
    u = np.clip((r.times_s - t0) / 4.0, 0, 1)
    want = 3.5 * (10 * u ** 3 - 15 * u ** 4 + 6 * u ** 5)              # Flash and Hogan 1985
    np.testing.assert_allclose(r.x[i], want, atol=1e-9)
    assert r.x[i][-1] == pytest.approx(3.5)
    assert np.all(r.gaps_m() > 0)
    # the new follower's braking stayed within b_safe
    assert np.min(r.acc[r.index("f")]) >= -spec.safe_decel_m_per_s2 - 1e-9
    assert float(min_jerk(0.5)) == pytest.approx(0.5)


def test_oncoming_vehicle_moves_toward_the_camera_in_the_keyframes():
    from poevp_optics.sources.motion import MotionSpec
    from poevp_optics.sources.vehicles import VehicleSpec

    vehicles = {"o": VehicleSpec(kind="suv", position_m=(3.5, 80.0), heading_deg=180.0),
                "a": VehicleSpec(kind="sedan", position_m=(0.0, 20.0))}
    motions = {"o_body": MotionSpec(kind="traffic", vehicle="o", velocity_m_per_s=(0.0, 0.0, -12.0)),
               "a_body": MotionSpec(kind="traffic", vehicle="a", velocity_m_per_s=(0.0, 0.0, 10.0)),
               "still": MotionSpec(kind="static")}
    out = traffic_motions(TrafficSpec(speed_spread=0.0), vehicles, motions, 2.0)
    assert out["still"] is motions["still"]
    o, a = out["o_body"], out["a_body"]
    assert o.kind == a.kind == "keyframes"
    assert o.offset_m(0.0)[2] == 0.0
    # 12 m/s toward us accelerating gently toward v0 = 13.9 m/s: between 12 and 13.9 m/s x 2 s
    assert -2 * 13.9 < o.offset_m(2.0)[2] < -2 * 12.0
    assert 2 * 10.0 < a.offset_m(2.0)[2] < 2 * 13.9


def test_the_loader_turns_traffic_motions_into_keyframes_and_names_bad_keys():
    from poevp_optics.core.exceptions import SceneError
    from poevp_optics.scene.load import load_scene
    from tests.conftest import SCENES

    spec = load_scene(SCENES / "toll_or_junction")
    m = spec.motion["near_body"]
    assert m.kind == "keyframes" and m.times_s[0] == 0.0 and m.times_s[-1] >= spec.timing.frames / spec.timing.fps
    assert "near_plate" in m.attached
    # the car behind the queue's van ends up standing at about s0 behind it (both in our lane)
    van, car = spec.vehicle["lead"], spec.vehicle["near"]
    from poevp_optics.sources.vehicles import shape_of

    gap = (van.position_m[1] + spec.motion["lead_body"].offset_m(0.5)[2]) - \
          (car.position_m[1] + m.offset_m(0.5)[2] + shape_of(car).length_m)
    assert 1.8 < gap < 2.5, gap
    # bad keys, one line each naming the key (the loader's own step, without reloading the scene)
    from poevp_optics.core.params import Where
    from poevp_optics.sources.motion import MotionSpec
    from poevp_optics.sources.traffic import resolve_scene_traffic

    ctx = Where("scene.toml", SceneError)
    good = {"near_body": MotionSpec(kind="traffic", vehicle="near")}
    for traffic, motions, key in (
            (TrafficSpec(lane_change_vehicle="nobody"), good, "traffic.lane_change_vehicle"),
            (TrafficSpec(), {"near_body": MotionSpec(kind="traffic", vehicle="ghost")}, "motion.near_body.vehicle"),
            (TrafficSpec(), {"near_body": MotionSpec(kind="linear", vehicle="near")}, "motion.near_body.vehicle"),
            (TrafficSpec(), {"a": MotionSpec(kind="traffic", vehicle="near"), **good}, "motion.near_body.vehicle")):
        with pytest.raises(SceneError) as e:
            resolve_scene_traffic(ctx, traffic, spec.vehicle, motions, spec.timing)
        assert str(e.value).startswith(f"scene.toml: {key}:") and "\n" not in str(e.value), str(e.value)

"""Photon-transfer check of the sensor model with the EMVA 1288 reference package (issue 3).

Flat fields from the 12-bit IMX253 preset (PRNU/DSNU off so the spatial terms do not enter the
temporal fit) are fed to `emva1288` exactly as a camera test bench would feed it: for each
exposure time a pair of dark frames (0 photons) and a pair of bright frames. The package must
recover the preset's system gain K, temporal dark noise, saturation capacity and DR.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

np.asfarray = getattr(np, "asfarray", lambda a, dtype=float: np.asarray(a, dtype=dtype))  # NumPy 2 shim
emva = pytest.importorskip("emva1288")
from emva1288.process import data as emva_data  # noqa: E402
from emva1288.process import results as emva_results  # noqa: E402
from emva1288.process import routines  # noqa: E402

from poevp_optics.camera.sensor import SensorSpec  # noqa: E402
from poevp_optics.camera.sensor import NoiseSwitches, Sensor, resolve_sensor  # noqa: E402

QE_525NM = 0.69                      # electrons per photon (assets/spectra/imx253_mono_qe.csv)


def _temporal(frames):
    """A frame pair as the package's temporal record: sums over all pixels (scalars)."""
    r = routines.get_int_imgs(frames)
    return {"sum": int(r["sum"].sum()), "pvar": int(r["pvar"].sum()), "dmean": float(r["dmean"])}


def test_emva1288_recovers_the_preset():
    from drjit.auto import Float

    p = resolve_sensor(SensorSpec(preset="IMX253", bits=12, prnu=0.0, dsnu_e=0.0))
    shape = (96, 96)
    sensor = Sensor(p, shape, NoiseSwitches(prnu=False, dsnu=False))
    n = shape[0] * shape[1]
    photons_per_s = p.full_well_e / QE_525NM / 0.010          # full well in 10 ms
    temporal, spatial = {}, {}
    seed = 1
    for t in np.linspace(0.0002, 0.0125, 50):                  # 2 % .. 125 % of saturation
        def frames(ph):
            nonlocal seed
            out = []
            for _ in range(2):
                seed += 1
                dn, _ = sensor.capture(Float(np.full(n, ph * QE_525NM, np.float32)), float(t), seed)
                out.append(np.array(dn).reshape(shape).astype(np.uint16))
            return out
        ph = float(photons_per_s * t)
        temporal[float(t)] = {0.0: _temporal(frames(0.0)), ph: _temporal(frames(ph))}
    t_sp = 0.005
    ph_sp = float(photons_per_s * t_sp)
    stack = lambda ph: [np.array(sensor.capture(Float(np.full(n, ph * QE_525NM, np.float32)), t_sp, 900 + i)[0]).reshape(shape).astype(np.uint16) for i in range(8)]  # noqa: E731
    spatial[t_sp] = {0.0: routines.get_int_imgs(stack(0.0)), ph_sp: routines.get_int_imgs(stack(ph_sp))}
    d = emva_data.Data1288({"temporal": temporal, "spatial": spatial,
                            "width": shape[1], "height": shape[0]}, loglevel=40)
    res = emva_results.Results1288(d.data, loglevel=40)

    dark_e = p.dark_current_e_per_s * 0.005
    sigma_d_true = math.sqrt(p.read_noise_e ** 2 + dark_e)   # temporal dark noise, e-
    print(f"EMVA: K {res.K:.5f} vs {p.gain_dn_per_e:.5f}; QE {res.QE:.2f} %; sigma_d {res.sigma_d:.3f} vs "
          f"{sigma_d_true:.3f} e-; u_e_sat {res.u_e_sat:.0f} vs {p.saturation_capacity_e:.0f} e-; DR {res.DR_dB():.2f} dB")
    assert res.K == pytest.approx(p.gain_dn_per_e, rel=0.05)
    assert res.QE / 100 == pytest.approx(QE_525NM, rel=0.05)
    assert res.sigma_d == pytest.approx(sigma_d_true, rel=0.05)
    assert res.u_e_sat == pytest.approx(p.saturation_capacity_e, rel=0.05)
    # the preset's own DR by the EMVA 1288 definition: saturation over the signal at SNR = 1,
    # mu_e,min = 1/2 + sqrt(1/4 + sigma_d^2 + sigma_q^2 / K^2)  (release 3.1, Eq. 37)
    sigma_q_e2 = (1 / 12) / p.gain_dn_per_e ** 2
    mu_min = 0.5 + math.sqrt(0.25 + sigma_d_true ** 2 + sigma_q_e2)
    dr_db = 20 * math.log10(p.saturation_capacity_e / mu_min)
    assert abs(res.DR_dB() - dr_db) < 1.0, (res.DR_dB(), dr_db)
    assert 69.0 < dr_db < 72.5                                  # "about 71 dB" (FACTS.md)

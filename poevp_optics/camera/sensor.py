"""Image sensor: photo-electrons, noise, full well, gain, offset and ADC (DrJit).

Conventions: electrons `_e`, digital numbers `_dn`; conversion gain `gain_dn_per_e` is DN per
electron (signal_dn = offset_dn + gain_dn_per_e * electrons).

Parameter table (`[sensor]`):

| key                  | type  | unit     | IMX253 preset | sweepable |
|----------------------|-------|----------|---------------|-----------|
| bits                 | int   | bit      | 8             | yes |
| full_well_e          | float | e-       | 10500         | yes |
| read_noise_e         | float | e- rms   | 2.6           | yes |
| gain_dn_per_e        | float | DN/e-    | auto: top code at full well - 5 read sigma | yes |
| offset_dn            | float | DN       | auto: 1 % of the code range      | yes |
| dark_current_e_per_s | float | e-/s     | 3.0           | yes |
| prnu                 | float | fraction | 0.005         | yes |
| dsnu_e               | float | e- rms   | 0.8           | yes |
| pixel_pitch_m        | float | m        | 3.45e-6       | yes |
| f_number             | float | -        | 2.8           | yes |
| optical_throughput   | float | fraction | 0.9           | yes |
| qe                   | str   | e-/photon| IMX253 table  | no  |
| poisson_sampler      | str   | -        | exact         | accuracy (POISSON_SAMPLERS) |

Registries: `SENSOR_PRESETS` (sensors by name, each citing its data), `POISSON_SAMPLERS`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry


@dataclass(frozen=True)
class SensorParams:
    """Resolved sensor parameters (SI units in names)."""

    name: str
    bits: int
    full_well_e: float
    read_noise_e: float
    gain_dn_per_e: float
    offset_dn: float
    dark_current_e_per_s: float
    prnu: float
    dsnu_e: float
    pixel_pitch_m: float
    f_number: float
    optical_throughput: float
    qe: str
    noise: bool = True
    seed: int = 0
    poisson_sampler: str = "exact"

    @property
    def max_dn(self) -> int:
        return (1 << self.bits) - 1

    @property
    def saturation_capacity_e(self) -> float:
        """Electrons at which the output clips: min(full well, ADC top code)."""
        return min(self.full_well_e, (self.max_dn - self.offset_dn) / self.gain_dn_per_e)


#: Sony IMX253 as in the paper's FLIR GS3-U3-123S6M-C, read out at 8 bit (paper Sec. 7).
#: Saturation 10.5 ke-, temporal dark noise 2.6 e-, DR about 72 dB: EMVA 1288 reports of the
#: same-pixel Pregius family (IMX250/252/253, 3.45 um) in Matrix Vision mvBlueCOUGAR-X/XD
#: manuals (saturation 10.5-10.7 ke-, dark noise 2.3-2.9 e-, DR 71.2-71.3 dB; FACTS.md).
#: Dark current 3 e-/s, DSNU 0.8 e-, PRNU 0.5 %: same reports (order of magnitude at 25 C).
#: Gain maps full well to the top code. f/2.8 and 0.9 lens transmission: our default C-mount
#: lens (the paper does not state its lens).
IMX253 = SensorParams(
    name="IMX253", bits=8, full_well_e=10500.0, read_noise_e=2.6, gain_dn_per_e=math.nan,
    offset_dn=math.nan, dark_current_e_per_s=3.0, prnu=0.005, dsnu_e=0.8, pixel_pitch_m=3.45e-6,
    f_number=2.8, optical_throughput=0.9, qe="file:spectra/imx253_mono_qe.csv")

#: A generic 12-bit machine-vision sensor (5.86 um, 32 ke-, 6 e- read noise; typical of
#: Sony IMX174-class EMVA data) with the same QE curve, for comparisons.
GENERIC = SensorParams(
    name="generic", bits=12, full_well_e=32000.0, read_noise_e=6.0, gain_dn_per_e=math.nan,
    offset_dn=math.nan, dark_current_e_per_s=10.0, prnu=0.01, dsnu_e=2.0, pixel_pitch_m=5.86e-6,
    f_number=2.8, optical_throughput=0.9, qe="file:spectra/imx253_mono_qe.csv")

SENSOR_PRESETS = Registry("sensor preset")
SENSOR_PRESETS.register("IMX253", IMX253, source="EMVA 1288 reports of the Sony Pregius IMX250/252/253 "
                        "(Matrix Vision mvBlueCOUGAR manuals); the paper's FLIR GS3-U3-123S6M-C")
SENSOR_PRESETS.register("generic", GENERIC, source="typical IMX174-class EMVA 1288 data (5.86 um, 32 ke-)")


#: Shot-noise samplers by name; entries registered below their functions.
POISSON_SAMPLERS = Registry("Poisson sampler")


@dataclass(frozen=True)
class SensorSpec:
    """[sensor]: preset plus overrides; NaN / -1 / "" mean "from the preset"."""

    preset: str = param("IMX253", choices=SENSOR_PRESETS)
    bits: int = param(-1, min=1, max=24, unset=-1)      # DN are float32: exact integers up to 2^24
    full_well_e: float = param(math.nan, gt=0)
    read_noise_e: float = param(math.nan, min=0)
    gain_dn_per_e: float = param(math.nan, gt=0)
    offset_dn: float = param(math.nan, min=0)
    dark_current_e_per_s: float = param(math.nan, min=0)
    prnu: float = param(math.nan, min=0, max=1)
    dsnu_e: float = param(math.nan, min=0)
    pixel_pitch_m: float = param(math.nan, gt=0, max=1e-3)
    f_number: float = param(math.nan, gt=0, max=1000.0)
    optical_throughput: float = param(math.nan, gt=0, max=1.0)
    qe: str = param("")
    noise: bool = param(True)
    seed: int = param(0, min=0, max=2**31 - 1)
    poisson_sampler: str = param("exact", choices=POISSON_SAMPLERS)   # accuracy


def resolve_sensor(spec: SensorSpec) -> SensorParams:
    """Preset values with the scene's overrides (NaN, -1 and "" mean "keep the preset")."""
    base = SENSOR_PRESETS[spec.preset]
    changes = {}
    for f in dataclasses.fields(SensorSpec):
        if f.name == "preset":
            continue
        v = getattr(spec, f.name)
        if (isinstance(v, float) and math.isnan(v)) or v == -1 or v == "":
            continue
        changes[f.name] = v
    p = dataclasses.replace(base, **changes)
    max_dn = (1 << p.bits) - 1
    if math.isnan(p.offset_dn):
        # a black level above 0 keeps dark noise from being clipped at 0 (EMVA 1288 trap)
        p = dataclasses.replace(p, offset_dn=float(round(0.01 * (max_dn + 1))))
    if math.isnan(p.gain_dn_per_e):
        # The ADC's top code sits 5 read-noise sigmas below full well, so a saturated pixel
        # reads exactly the top code with no noise, as on real cameras (EMVA 1288 saturation
        # is that clip); the saturation capacity is then full well - 5 sigma_read.
        usable = max(p.full_well_e - 5.0 * p.read_noise_e, 0.5 * p.full_well_e)
        p = dataclasses.replace(p, gain_dn_per_e=(max_dn - p.offset_dn) / usable)
    if p.offset_dn >= max_dn:
        raise ValueError(f"sensor.offset_dn = {p.offset_dn} leaves no codes below {max_dn}")
    return p


def pixel_etendue_m2_sr(p: SensorParams) -> float:
    """Pixel area times the projected solid angle of an f/N cone: A pi / (4 N^2) (m^2 sr).

    Exact for an aplanatic system with working f-number N = 1 / (2 sin(theta)); electrons =
    photon radiance (e- s-1 m-2 sr-1) x this x optical throughput x time.
    """
    return p.pixel_pitch_m ** 2 * math.pi / (4.0 * p.f_number ** 2)


@dataclass(frozen=True)
class NoiseSwitches:
    """Which effects are on (a table, not an integer flag: STYLE.md 11)."""

    shot: bool = True
    read: bool = True
    dark_current: bool = True
    prnu: bool = True
    dsnu: bool = True
    quantization: bool = True

    @classmethod
    def off(cls) -> "NoiseSwitches":
        return cls(False, False, True, False, False, True)


def poisson(lam, rng):
    """Exact Poisson variates for a DrJit Float array of means `lam` (float32 in, float32 out).

    lambda < 10: multiplication (Knuth 1969, TAOCP vol. 2, 3.4.1): exact, mean 1 + lambda uniforms.
    lambda >= 10: PTRS transformed rejection with squeeze (Hormann 1993, Insurance Math. Econ.
    12, 39-45), exact; the acceptance test runs in float64 so that -lambda + k log(lambda) -
    lgamma(k + 1) keeps ~1e-7 absolute accuracy up to lambda ~ 1e9 (float32 would lose it
    above ~1e4). Results are exact integers up to 2^24 ~ 1.7e7 e- and rounded to float32
    (relative spacing 6e-8) above: sampling error is far below the shot noise 1/sqrt(lambda).
    """
    import drjit as dr
    from drjit.auto import Bool, Float, Float64

    lam = dr.maximum(Float(lam), 0.0)
    small = lam < 10.0
    # ---- multiplication method on the small lanes (others run zero iterations)
    lam_s = dr.select(small, lam, 0.0)
    limit = dr.exp(-lam_s)
    k_s = dr.zeros(Float, dr.width(lam))
    prod = dr.ones(Float, dr.width(lam))

    def cond_s(rng, k, p):
        return p > limit

    def body_s(rng, k, p):
        p = p * rng.next_float32()
        k = dr.select(p > limit, k + 1.0, k)
        return rng, k, p

    rng, k_s, prod = dr.while_loop(state=(rng, k_s, prod), cond=cond_s, body=body_s)
    # ---- PTRS on the large lanes
    lam_b = Float64(dr.select(small, 10.0, lam))
    slam = dr.sqrt(lam_b)
    loglam = dr.log(lam_b)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    inv_alpha = 1.1239 + 1.1328 / (b - 3.4)
    vr = 0.9277 - 3.6224 / (b - 2.0)
    done = Bool(small)
    k_b = dr.zeros(Float64, dr.width(lam))

    def cond_b(rng, k, done):
        return ~done

    def body_b(rng, k, done):
        u = rng.next_float64() - 0.5
        v = rng.next_float64()
        us = 0.5 - dr.abs(u)
        kk = dr.floor((2.0 * a / us + b) * u + lam_b + 0.43)
        quick = (us >= 0.07) & (v <= vr)
        reject = (kk < 0.0) | ((us < 0.013) & (v > us))
        lhs = dr.log(v) + dr.log(inv_alpha) - dr.log(a / (us * us) + b)
        rhs = -lam_b + kk * loglam - dr.lgamma(kk + 1.0)
        accept = quick | (~reject & (lhs <= rhs))
        k = dr.select(~done & accept, kk, k)
        return rng, k, done | accept

    rng, k_b, done = dr.while_loop(state=(rng, k_b, done), cond=cond_b, body=body_b)
    return dr.select(small, k_s, Float(k_b)), rng


def normal(rng, n):
    """Standard normal variates (Box-Muller), DrJit Float of width n."""
    import drjit as dr

    u1 = rng.next_float32()
    u2 = rng.next_float32()
    return dr.sqrt(-2.0 * dr.log(dr.maximum(1.0 - u1, 1e-30))) * dr.cos(2.0 * dr.pi * u2), rng


def gaussian_counts(lam, rng):
    """Normal approximation of Poisson counts: round(lambda + sqrt(lambda) z), clipped at 0 (the
    central-limit form ISETCam uses above 25 e-; FACTS.md). Biased at low counts: for studies of
    what the exact sampler costs, not for the default."""
    import drjit as dr
    from drjit.auto import Float

    lam = dr.maximum(Float(lam), 0.0)
    z, rng = normal(rng, dr.width(lam))
    return dr.maximum(dr.round(lam + dr.sqrt(lam) * z), 0.0), rng


POISSON_SAMPLERS.register("exact", poisson, source="Knuth 1969 (TAOCP 2, 3.4.1) below 10 e-, PTRS "
                          "transformed rejection (Hormann 1993) above: exact")
POISSON_SAMPLERS.register("gaussian", gaussian_counts, source="normal approximation N(lambda, lambda), "
                          "rounded (ISETCam sensorCompute above 25 e-)")


class Sensor:
    """A sensor instance: parameters plus its fixed-pattern noise (drawn once from its seed).

    State is real here: PRNU and DSNU maps belong to the physical chip and must not be redrawn
    per frame (ISETCam's per-call redraw is wrong for video; FACTS.md).
    """

    def __init__(self, params: SensorParams, shape: tuple[int, int],
                 switches: NoiseSwitches | None = None):
        from drjit.auto import Float

        self.p = params
        self.shape = tuple(shape)
        self.switches = switches or (NoiseSwitches() if params.noise else NoiseSwitches.off())
        g = np.random.default_rng(np.random.SeedSequence([params.seed, 0x5E45]))
        n = shape[0] * shape[1]
        prnu = g.standard_normal(n) * params.prnu if self.switches.prnu else np.zeros(n)
        dsnu = g.standard_normal(n) * params.dsnu_e if self.switches.dsnu else np.zeros(n)
        self.gain_map = Float(np.maximum(1.0 + prnu, 0.0).astype(np.float32))
        self.dsnu_e = Float(dsnu.astype(np.float32))
        self.random_draws = 0           # counted for the "noise off draws nothing" check

    def mean_electrons(self, signal_e, exposure_s: float):
        """Expected collected electrons: PRNU x photo-electrons + dark current x t (>= 0)."""
        import drjit as dr

        dark = self.p.dark_current_e_per_s * exposure_s if self.switches.dark_current else 0.0
        return dr.maximum(signal_e * self.gain_map + dark, 0.0)

    def capture(self, signal_e, exposure_s: float, seed: int):
        """Photo-electrons (DrJit Float, flattened) -> (DN, electrons after clip) DrJit Floats.

        Order: PRNU/dark mean -> Poisson shot noise -> full-well clip -> Gaussian read noise
        and the pixel's DSNU offset (zero-mean, in the analog chain: adding it to the Poisson
        mean would need a clip at 0 there and bias dark pixels by +0.4 sigma_DSNU) -> gain and
        black offset -> ADC rounding -> clip to [0, 2^bits - 1].
        """
        import drjit as dr
        from drjit.auto import PCG32, UInt32

        p, sw = self.p, self.switches
        if not bool(dr.all(dr.isfinite(signal_e), axis=None)):
            # a NaN mean never satisfies the Poisson sampler's acceptance test (an endless loop)
            raise ValueError("sensor input holds NaN/Inf photo-electrons: check the radiance "
                             "(emitter scale, render) before the sensor")
        mean = self.mean_electrons(signal_e, exposure_s)
        n = dr.width(mean)
        need_rng = sw.shot or (sw.read and p.read_noise_e > 0)
        if need_rng:
            # opaque seed: a literal would be baked into the kernel and force a recompile
            # (~60 ms) for every new frame seed
            rng = PCG32(size=n, initstate=dr.opaque(UInt32, seed & 0xFFFFFFFF),
                        initseq=dr.arange(UInt32, n))
            self.random_draws += n
        e = mean
        if sw.shot:
            e, rng = POISSON_SAMPLERS[p.poisson_sampler](mean, rng)
        e = dr.minimum(e, p.full_well_e)
        e_read = e + self.dsnu_e
        if sw.read and p.read_noise_e > 0:
            z, rng = normal(rng, n)
            e_read = e_read + p.read_noise_e * z
        dn = p.offset_dn + p.gain_dn_per_e * e_read
        if sw.quantization:
            dn = dr.round(dn)
        dn = dr.clip(dn, 0.0, float(p.max_dn))
        return dn, e

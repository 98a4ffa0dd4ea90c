"""Mitsuba samplers by name (`render.sampler`, an accuracy setting), each citing Mitsuba's docs.

A sampler decides where in a pixel's sample space (film position, lens, time, wavelength, light
and BSDF choices) the spp samples fall. All of these are randomised: a seed gives an
independent draw (independent sampler) or an independent random scrambling/permutation of a
stratified or low-discrepancy point set, so each render is an unbiased estimate and the spread
of independent-seed renders is an honest error of their mean (randomised quasi-Monte Carlo:
Owen, "Monte Carlo theory, methods and examples", 2013, ch. 17; L'Ecuyer & Lemieux 2002).
That estimate is what `Renderer.render_with_error` returns; tests/physics/test_sampler_error.py
checks it against the true error.

Mitsuba rounds some sample counts (measured with Mitsuba 3.9: `ldsampler` to a power of 4,
`orthogonal` to a prime squared, `stratified` to a square, `multijitter` to a near-square
product); `sample_count` asks Mitsuba itself, and the renderer reports the spp it actually used.
"""

from __future__ import annotations

from dataclasses import dataclass

from poevp_optics.core.registry import Registry

_DOCS = "Mitsuba 3 documentation, Plugin reference > Samplers (mitsuba.readthedocs.io/en/latest/src/generated/plugins_samplers.html)"


@dataclass(frozen=True)
class SamplerKind:
    """A Mitsuba sampler plugin and what its randomisation is."""

    plugin: str
    randomised_by: str     # what the seed changes (why independent seeds give independent estimates)

    def mitsuba_dict(self, sample_count: int = 1) -> dict:
        return {"type": self.plugin, "sample_count": int(sample_count)}


SAMPLERS = Registry("sampler")
SAMPLERS.register("independent", SamplerKind("independent", "independent uniform draws"),
                  source=f"{_DOCS}: Independent sampler (`independent`)",
                  doc="iid uniform samples: error ~ spp^-1/2")
SAMPLERS.register("stratified", SamplerKind("stratified", "a random jitter in each stratum"),
                  source=f"{_DOCS}: Stratified sampler (`stratified`)",
                  doc="jittered strata per dimension, sample count rounded up to a square")
SAMPLERS.register("multijitter", SamplerKind("multijitter", "random jitter and shuffled sub-strata"),
                  source=f"{_DOCS}: Correlated multi-jittered sampler (`multijitter`); "
                         "Kensler, 'Correlated Multi-Jittered Sampling', Pixar TM 13-01, 2013",
                  doc="jittered in 2D and in each 1D projection; any count near a product of two")
SAMPLERS.register("ldsampler", SamplerKind("ldsampler", "random scrambling of the (0,2)-sequence"),
                  source=f"{_DOCS}: Low discrepancy sampler (`ldsampler`); Kollig & Keller, "
                         "'Efficient multidimensional sampling', Eurographics 2002",
                  doc="scrambled (0,2)-sequence; Mitsuba 3.9 rounds the count up to a power of 4")
SAMPLERS.register("orthogonal", SamplerKind("orthogonal", "random permutations of the orthogonal array"),
                  source=f"{_DOCS}: Orthogonal array sampler (`orthogonal`); Jarosz et al., "
                         "'Orthogonal array sampling for Monte Carlo rendering', EGSR 2019",
                  doc="strength-2 orthogonal array (Bush construction); count rounded up to a prime squared")


def sample_count(name: str, spp: int) -> int:
    """The spp Mitsuba renders when asked for `spp` with sampler `name` (a variant must be set)."""
    import mitsuba as mi

    s = mi.load_dict(SAMPLERS[name].mitsuba_dict(4))
    s.set_sample_count(int(spp))
    return int(s.sample_count())

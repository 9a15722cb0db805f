"""The embedded default: a synthetic population built from the published statistics.

No measured face database can be downloaded, so facestats ships a population
whose ground truth follows Weyrich et al. 2006 (numbers from
:mod:`facestats.core.published`) and pushes it through the real pipeline (simulated
captures, then fitting).  Every number chosen here is listed with the published
figure it reproduces.

Demographics (Table 2, §7)
    149 subjects with the exact skin type × gender counts of Table 2 (I-II 8 M /
    6 F, III 49/18, IV 40/8, V 13/2, VI 4/1; two of the I-II subjects, one man
    and one woman, are type I: "we measured only two individuals of skin type I")
    and the exact age-group × gender counts of §7 (20s or younger 61/18, 30s
    37/10, 40s 10/2, 50s or older 6/5), ages uniform within the group (18-29,
    30-39, 40-49, 50-69), age groups assigned to subjects by a seeded shuffle
    within each gender.  One of them, the type III man whose age is nearest 34
    (:func:`condition_person`), is also measured under the six other
    conditions of §7 ("we also measured one male subject under several
    external conditions"): records ``<his id>-<condition>`` of the same person,
    so the normal-condition population stays the 149 of Table 2.  (Before
    2026-12-06 he was a 150th person, ``P150``, whose normal record entered the
    population statistics: 50 type III men against Table 2's 49; found by an
    audit.)

Albedo (linear RGB, total diffuse reflectance)
    The colour of each skin type is anchored in the measured reflectance spectra
    of the ColorChecker "light skin" and "dark skin" patches shipped with
    colour-science (BabelColor average): the spectrum of a subject is
    R(λ) = R_light(λ)^(1-t) · R_dark(λ)^t, a Beer-Lambert mixing of absorbers
    (melanin-like), rendered to linear sRGB under D65 by colour-science.  The
    melanin index t per skin type is ``SKIN_TYPE_MELANIN`` (I: -0.25 … VI: 1.25,
    "dark skin" ≈ type V), with a per-subject spread of 0.08.  The map adds
    smooth low-frequency variation (±6 %), regional tints (redder lips, nose and
    cheeks, darker eyebrows and under-eye), pores (dark 0.3 mm dots), and
    optionally freckles and moles.

Specular BRDF (Fig. 15, Fig. 16)
    Region means of the Torrance-Sparrow (ρs, m) in ``TS_REGION_MEAN``, ordered as
    §7 reports: the nose (6) has the smallest m; nose, eyebrows, eyelids, lips and
    forehead (6, 3, 4, 8, 2) the highest ρs; lips, mustache, eyebrows, chin and
    beard (8, 1, 3, 9, 10) the largest spread (``TS_REGION_CV``), 1.5× larger for
    men in the facial-hair regions (1, 3, 9, 10).  Ranges follow the Fig. 15 axes
    (m ≈ 0.23-0.31, ρs ≈ 0.18-0.32).  Each subject's region means shift with
    skin type, gender and age along fixed loading patterns
    (``LOADINGS``), scaled so that the canonical correlation analysis of the
    149 × 23 matrix reproduces Fig. 16 (principal correlations 0.768 and 0.585,
    direct correlations 0.766 skin type, 0.573 gender, 0.537 age; see
    ``tests/acquire/test_population.py``).  The directions of the effects are our
    choice (the paper publishes strengths only): darker types shinier (higher
    ρs), women smoother in the facial-hair regions, older skin rougher; the
    patterns are orthogonal, so CCA improves little on the direct correlations.  Blinn-Phong truth follows
    from Torrance-Sparrow by the Beckmann-Phong correspondence n = 2/m² − 2
    (Walter et al. 2007) and ρs_BP = ρs_TS · F_r(0) (equal peak value at normal
    incidence, and equal albedo for narrow lobes).

Translucency (Table 1, §5.4, Fig. 11, Fig. 14)
    σtr per site (cheek, forehead, neck) and channel is log-normal with the
    Table 1 mean and spread; within a subject, sites share a subject factor
    (correlation 0.5) and channels correlate (0.6).  **Table 1's "Var." column is
    read as a standard deviation** (``table1_spread="std"``): taken as a variance,
    the red-channel spread (CV 75 %) would give 149 subjects ℓd from about 0.6 to
    10 mm, against §5.4's "ℓd do not vary much between individuals" and the
    extremes of Fig. 11 (1.09-2.81 mm in red); as a standard deviation it gives
    about 1.1-3.3 mm.  ``table1_spread="variance"`` reproduces the literal
    reading.  σ's and σa at each site follow from the site's albedo and σtr
    through §5.4 (:func:`facestats.model.dipole.scattering_from_albedo`), so
    darker skin has higher absorption and lower scattering (Fig. 14); the
    subject's own σ's and σa come from its α_avg and the population's σtrAvg.

Conditions (§7)
    Multiplicative effects on (ρs, m) relative to "normal" (``CONDITION_EFFECTS``):
    lotion (1.35, 0.85) and hot (1.20, 0.92) shinier, sweaty (1.25, 0.90),
    cold (0.85, 1.10) and powder (0.60, 1.30) more matte, makeup (0.80, 1.15) with
    an evened albedo texture; "noticeable differences … especially between
    lotion / hot and cold / powder".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.acquire.synthetic.texture import albedo_map, smooth_noise
from facestats.core.conventions import (
    CHANNELS,
    CONDITIONS,
    DEFAULT_FACE,
    DEFAULT_MAP_SIZE,
    DEFAULT_SEED,
    REGION_IDS,
    SITES,
)
from facestats.core.published import AGE_COUNTS, ETA_SKIN, TABLE1_MEAN, TABLE1_VAR, TABLE2_COUNTS
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import ValidationError
from facestats.face.named import face_geometry
from facestats.model import dipole, fresnel
from facestats.model.skin_colour import skin_albedo

__all__ = [
    "SKIN_TYPE_MELANIN",
    "TS_REGION_MEAN",
    "TS_REGION_CV",
    "LOADINGS",
    "CONDITION_EFFECTS",
    "SubjectTruth",
    "Population",
    "synthesize_population",
    "check_population_id",
    "default_population",
    "condition_person",
]

#: Melanin index t per Fitzpatrick type (0 = ColorChecker "light skin", 1 = "dark skin").
SKIN_TYPE_MELANIN = {1: -0.25, 2: -0.10, 3: 0.15, 4: 0.45, 5: 0.85, 6: 1.25}
#: Per-subject spread of t.
MELANIN_SPREAD = 0.08

#: Torrance-Sparrow (ρs, m) region means (Fig. 15 ordering, see the module docstring).
TS_REGION_MEAN = {
    1: (0.20, 0.300),  # mustache
    2: (0.27, 0.270),  # forehead
    3: (0.28, 0.290),  # eyebrows
    4: (0.28, 0.280),  # eyelids
    5: (0.22, 0.280),  # under-eye (region 5)
    6: (0.31, 0.230),  # nose: highest rho_s, smallest m
    7: (0.21, 0.280),  # cheeks
    8: (0.27, 0.260),  # lips
    9: (0.22, 0.300),  # chin
    10: (0.19, 0.310),  # beard
}
#: Within-region texel spread (coefficient of variation of ρs and m).
TS_REGION_CV = {1: 0.12, 2: 0.05, 3: 0.12, 4: 0.05, 5: 0.05, 6: 0.05, 7: 0.05, 8: 0.15, 9: 0.12, 10: 0.12}
#: Facial-hair regions, whose spread is larger for men (§7).
HAIR_REGIONS = (1, 3, 9, 10)
HAIR_FACTOR_MEN = 1.5
#: Between-subject spread of the region means around the covariate model (relative).
BETWEEN_SUBJECT_CV = 0.035

#: Relative effect of one standard deviation of each covariate on (ρs, m) per region:
#: patterns (unit-free) that the strengths below scale.
#: The three patterns are orthogonal in the 20-dimensional space of relative
#: region-mean changes, so, as Fig. 16 found, canonical correlation barely
#: improves on the direct correlations: skin type scales ρs in every region,
#: gender contrasts m between the facial-hair regions and the rest (women
#: smoother where men have hair), age raises m everywhere (older skin rougher).
LOADINGS = {
    "skin_type": {r: (1.0, 0.0) for r in REGION_IDS},
    "gender": {r: (0.0, -1.0 if r in HAIR_REGIONS else 2.0 / 3.0) for r in REGION_IDS},
    "age": {r: (0.0, 1.0) for r in REGION_IDS},
}
#: Strengths (relative change per standard deviation of the covariate), found by
#: Monte-Carlo search (``scripts/calibrate_population.py``, 8 seeds per setting, on the embedded
#: default's face and map size: ICT-FaceKit at 48²) so that the expected sample CCA of the 149
#: subjects' truth matches Fig. 16: it gives principal correlations 0.773, 0.600 and direct
#: correlations 0.763, 0.561, 0.539 (published 0.768, 0.585; 0.766, 0.573, 0.537).  Fewer
#: texels per region make region means noisier: the procedural head at 48² was calibrated at
#: skin type 0.0145 (the same gender and age), which on the ICT face gives 0.748 and 0.735.
EFFECT_STRENGTH = {"skin_type": 0.016, "gender": 0.010, "age": 0.007}

#: (factor on ρs, factor on m) per condition, relative to normal (§7).
CONDITION_EFFECTS = {
    "normal": (1.00, 1.00),
    "cold": (0.85, 1.10),
    "hot": (1.20, 0.92),
    "sweaty": (1.25, 0.90),
    "makeup": (0.80, 1.15),
    "lotion": (1.35, 0.85),
    "powder": (0.60, 1.30),
}

#: Age ranges of the §7 groups used for drawing ages.
_AGE_RANGES = {"20s": (18, 29), "30s": (30, 39), "40s": (40, 49), "50s+": (50, 69)}
#: Correlations of the σtr draws.
_SITE_CORRELATION = 0.5
_CHANNEL_CORRELATION = 0.6


@dataclass
class SubjectTruth:
    """Ground truth of one synthetic subject (maps on the UV grid, [v, u] indexed).

    Attributes
    ----------
    subject_id : str
        ``"S001"`` … ``"S149"``, or ``"<person>-<condition>"`` for the condition series.
    person_id : str
        The person measured (several records may be one person).
    age : int
        Years.
    gender : {"M", "F"}
    skin_type : int
        Fitzpatrick skin type, 1 to 6.
    condition : str
        One of :data:`facestats.core.conventions.CONDITIONS`.
    region_map : ndarray of uint8, shape (n, n)
        Face region of each texel (:data:`~facestats.core.conventions.REGION_IDS`; 0 off the face).
    albedo : ndarray, shape (n, n, 3)
        Total diffuse reflectance, linear RGB.
    ts_rho_s, ts_m : ndarray, shape (n, n)
        Torrance-Sparrow ρs and m; 0 off the face.
    bp_rho_s, bp_exponent : ndarray, shape (n, n)
        Blinn-Phong ρs and exponent n; 0 off the face.
    site_sigma_tr : ndarray, shape (site, channel)
        σtr at the sites of :data:`~facestats.core.conventions.SITES`, mm⁻¹.
    site_albedo : ndarray, shape (site, channel)
        Total diffuse reflectance at each site.
    sigma_tr : ndarray, shape (channel,)
        σtrAvg, mm⁻¹, set by the population.
    seed : int
        Default seed of a simulated capture's noise
        (:meth:`~facestats.acquire.synthetic.simulate.DomeSimulator.simulate`).
    features : dict
        Texture features drawn (the population's: ``freckles``, ``moles``, ``melanin``).
    geometry : str
        ``FaceGeometry.name`` of the face the maps are laid out on (``"ict-48"``); ``""`` if unknown.
    """

    subject_id: str
    person_id: str
    age: int
    gender: str
    skin_type: int
    condition: str
    region_map: np.ndarray
    albedo: np.ndarray
    ts_rho_s: np.ndarray
    ts_m: np.ndarray
    bp_rho_s: np.ndarray
    bp_exponent: np.ndarray
    site_sigma_tr: np.ndarray
    site_albedo: np.ndarray
    sigma_tr: np.ndarray = None
    seed: int = 0
    features: dict = field(default_factory=dict)
    geometry: str = ""

    @property
    def face(self) -> np.ndarray:
        """Texels that belong to the face (region > 0)."""
        return self.region_map > 0

    @property
    def albedo_avg(self) -> np.ndarray:
        """α_avg: mean albedo over the face, per channel (Weyrich §5.4)."""
        return self.albedo[self.face].mean(axis=0).astype(np.float64)

    @property
    def site_scattering(self):
        """(σ's, σa) per site and channel from the site albedo and σtr (§5.4)."""
        return dipole.scattering_from_albedo(self.site_albedo, self.site_sigma_tr, ETA_SKIN)

    @property
    def scattering(self):
        """The subject's homogeneous (σ's, σa) from α_avg and σtrAvg (§5.4)."""
        return dipole.scattering_from_albedo(self.albedo_avg, self.sigma_tr, ETA_SKIN)

    def metadata(self) -> dict:
        """The subject's metadata attributes (ids, age, gender, skin type, condition)."""
        return {
            "subject_id": self.subject_id,
            "person_id": self.person_id,
            "age": int(self.age),
            "gender": self.gender,
            "skin_type": int(self.skin_type),
            "condition": self.condition,
        }

    def to_dataset(self):
        """The ground truth as an xarray Dataset on the subject schema's dims."""
        import xarray as xr

        n = self.region_map.shape[0]
        sp, sa = self.site_scattering
        ssp, ssa = self.scattering
        ds = xr.Dataset(
            {
                "region": (("v", "u"), self.region_map),
                "albedo": (("v", "u", "channel"), self.albedo),
                "ts_rho_s": (("v", "u"), self.ts_rho_s),
                "ts_m": (("v", "u"), self.ts_m),
                "bp_rho_s": (("v", "u"), self.bp_rho_s),
                "bp_exponent": (("v", "u"), self.bp_exponent),
                "site_sigma_tr": (("site", "channel"), self.site_sigma_tr),
                "site_sigma_s_prime": (("site", "channel"), sp),
                "site_sigma_a": (("site", "channel"), sa),
                "albedo_avg": (("channel",), self.albedo_avg),
                "sigma_tr": (("channel",), np.asarray(self.sigma_tr, float)),
                "sigma_s_prime": (("channel",), ssp),
                "sigma_a": (("channel",), ssa),
            },
            coords={
                "u": (np.arange(n) + 0.5) / n,
                "v": (np.arange(n) + 0.5) / n,
                "channel": list(CHANNELS),
                "site": list(SITES),
            },
            attrs=dict(
                self.metadata(),
                kind="truth",
                seed=int(self.seed),
                geometry=self.geometry,
                **{f"feature_{k}": v for k, v in self.features.items()},
            ),
        )
        return ds


@dataclass
class Population:
    """A synthetic population: subjects' ground truth and the population σtrAvg.

    Indexing takes a position or a subject id (``population["S001"]``).

    Attributes
    ----------
    subjects : list of SubjectTruth
        The subjects drawn, S001… first, then the condition series.
    sigma_tr_avg : ndarray, shape (channel,)
        σtrAvg, mm⁻¹: the mean over the 149 subjects of their cheek and forehead σtr (§5.4).
    seed : int
        The seed the population was drawn with.
    settings : dict
        ``map_size``, ``table1_spread`` and ``conditions`` of :func:`synthesize_population`.
    """

    subjects: list
    sigma_tr_avg: np.ndarray
    seed: int
    settings: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.subjects)

    def __getitem__(self, key):
        if isinstance(key, str):
            for s in self.subjects:
                if s.subject_id == key:
                    return s
            raise KeyError(key)
        return self.subjects[key]

    def table(self):
        """Metadata of every subject as a pandas DataFrame indexed by subject_id."""
        import pandas as pd

        return pd.DataFrame([s.metadata() for s in self.subjects]).set_index("subject_id")


def _brdf_maps(region_map, region_means, rng, gender):
    """Texel maps of (ρs, m) from per-region means with smooth log-normal within-region spread."""
    n = region_map.shape[0]
    z1 = smooth_noise(rng, (n, n), max(n / 48, 0.6))
    z2 = smooth_noise(rng, (n, n), max(n / 48, 0.6))
    rho = np.zeros((n, n))
    m = np.zeros((n, n))
    for r in REGION_IDS:
        sel = region_map == r
        cv = TS_REGION_CV[r] * (HAIR_FACTOR_MEN if (gender == "M" and r in HAIR_REGIONS) else 1.0)
        mr, mm = region_means[r]
        # ρs and m vary together a little (correlation -0.3) within a region.
        rho[sel] = mr * np.exp(cv * z1[sel] - 0.5 * cv * cv)
        m[sel] = mm * np.exp(cv * (-0.3 * z1[sel] + np.sqrt(1 - 0.09) * z2[sel]) - 0.5 * cv * cv)
    return rho.astype(np.float32), m.astype(np.float32)


def _bp_from_ts(rho_s, m):
    """Blinn-Phong truth from Torrance-Sparrow: n = 2/m² − 2 (Beckmann-Phong correspondence,
    Walter et al. 2007), ρs_BP = ρs F_r(0) with F_r(0) ≈ 0.0255 at η = 1.38 (module docstring)."""
    f0 = float(fresnel.fresnel_reflectance(1.0, ETA_SKIN))
    with np.errstate(divide="ignore"):
        n = np.where(m > 0, 2 / np.maximum(m, 1e-6) ** 2 - 2, 0)
    return (rho_s * f0).astype(np.float32), n.astype(np.float32)


def _demographics(rng):
    """Skin type, gender and age of the 149 subjects (Table 2 and §7 counts, exact)."""
    rows = []
    for gender, gi in (("M", 0), ("F", 1)):
        types = []
        for st, counts in TABLE2_COUNTS.items():
            types += [st] * counts[gi]
        types = np.array(types)
        # Two of the I-II group are type I (one man, one woman; §7).
        types[np.nonzero(types == 2)[0][0]] = 1
        groups = []
        for label, counts in AGE_COUNTS.items():
            groups += [label] * counts[gi]
        groups = np.array(groups)[rng.permutation(len(groups))]
        for st, grp in zip(types, groups):
            lo, hi = _AGE_RANGES[grp]
            rows.append((int(st), gender, int(rng.integers(lo, hi + 1))))
    order = rng.permutation(len(rows))
    return [rows[i] for i in order]


def _standardise(x):
    """Zero mean, unit (population) standard deviation."""
    x = np.asarray(x, float)
    return (x - x.mean()) / x.std()


def _sigma_tr_draws(rng, n, spread):
    """σtr (n, site, channel), log-normal with Table 1 means and spreads, correlated sites/channels."""
    sites = SITES
    mean = np.stack([TABLE1_MEAN[s] for s in sites])
    var_col = np.stack([TABLE1_VAR[s] for s in sites])
    sd = var_col if spread == "std" else np.sqrt(var_col)
    s_log = np.sqrt(np.log1p((sd / mean) ** 2))  # log-normal shape giving that mean and sd
    mu_log = np.log(mean) - 0.5 * s_log**2
    ch_cov = np.full((3, 3), _CHANNEL_CORRELATION) + (1 - _CHANNEL_CORRELATION) * np.eye(3)
    chol = np.linalg.cholesky(ch_cov)
    subj = rng.standard_normal((n, 1, 3)) @ chol.T
    own = rng.standard_normal((n, 3, 3)) @ chol.T
    z = np.sqrt(_SITE_CORRELATION) * subj + np.sqrt(1 - _SITE_CORRELATION) * own
    return np.exp(mu_log[None] + s_log[None] * z)


def synthesize_population(
    seed: int = 2006,
    map_size: int = 48,
    *,
    geometry=None,
    conditions: bool = True,
    table1_spread: str = "std",
    freckle_fraction: float = 0.15,
    subjects=None,
):
    """Draw the synthetic population (module docstring), deterministic for a seed.

    Parameters
    ----------
    seed : int
        Seed of every random draw (≥ 0): the same seed gives bit-identical truth.
    map_size : int
        Side of the UV maps (≥ 2; must match the capture geometry's ``map_size``).
    geometry : FaceGeometry, optional
        Geometry whose ``region_map`` to use (its name is recorded as each truth's ``geometry``);
        default the face of the embedded default (:data:`facestats.core.conventions.DEFAULT_FACE`,
        the ICT-FaceKit face) with lumitexels on a ``map_size``² grid.
    conditions : bool
        Include the records of :func:`condition_person` under the six conditions other than normal (§7).  The
        149 subjects' draws do not depend on it.
    table1_spread : {"std", "variance"}
        How to read Table 1's "Var." column (module docstring).
    freckle_fraction : float
        Fraction of subjects given freckles, in [0, 0.57]: a subject of skin type
        I-III is freckled with probability ``freckle_fraction / 0.57``.
    subjects : collection of str, optional
        Materialise only these subject ids (``"S001"`` … ``"S149"``, and
        ``"<condition person>-<condition>"`` with ``conditions``; at high resolution the maps of
        all 155 subjects would not fit in memory).  Every draw is the same as in
        the full population: each subject has its own random stream.

    Returns
    -------
    Population
    """
    check_choice(table1_spread, "table1_spread", ("std", "variance"))
    check_integer(seed, "seed", 0)
    check_integer(map_size, "map_size", 2)
    as_finite(freckle_fraction, "freckle_fraction", 0, 0.57)
    if isinstance(subjects, str):
        raise ValidationError(f"subjects must be a collection of subject ids, got the string {subjects!r}")
    if geometry is None:
        geometry = face_geometry(DEFAULT_FACE, map_size)
    region_map = geometry.region_map
    if region_map is None or region_map.shape != (map_size, map_size):
        raise ValidationError(
            f"geometry must carry a {map_size}x{map_size} region_map, "
            f"got {None if region_map is None else region_map.shape}"
        )
    texel_mm = float(np.sqrt(np.median(geometry.area))) * (geometry.meta.get("lumitexel_grid", map_size) / map_size)
    draws = _population_draws(seed, table1_spread)
    wanted = None if subjects is None else set(subjects)
    _check_wanted(wanted, draws, conditions)
    found = _normal_subjects(draws, region_map, texel_mm, freckle_fraction, wanted)
    if conditions:
        found += _condition_subjects(draws, region_map, texel_mm, freckle_fraction, wanted)
    # σtrAvg: mean over subjects of cheek and forehead (neck excluded), §5.4.
    sigma_tr_avg = draws.sigma_tr[: len(draws.skin_type), :2].mean(axis=(0, 1))
    for s in found:
        s.sigma_tr = sigma_tr_avg
        s.geometry = str(geometry.name)
    return Population(
        subjects=found,
        sigma_tr_avg=sigma_tr_avg,
        seed=int(seed),
        settings={"map_size": int(map_size), "table1_spread": table1_spread, "conditions": bool(conditions)},
    )


@dataclass
class _Draws:
    """The population-level random draws, in the order the streams are consumed."""

    skin_type: np.ndarray
    gender: np.ndarray
    age: np.ndarray
    z_cov: dict
    melanin: np.ndarray
    base_rgb: np.ndarray
    sigma_tr: np.ndarray
    between: np.ndarray
    subject_seeds: list

    def region_means(self, i, zs):
        """(ρs, m) means per region of subject ``i`` with standardised covariates ``zs`` (module docstring)."""
        out = {}
        for k, r in enumerate(REGION_IDS):
            rho0, m0 = TS_REGION_MEAN[r]
            drho = sum(EFFECT_STRENGTH[c] * LOADINGS[c][r][0] * zs[c] for c in EFFECT_STRENGTH)
            dm = sum(EFFECT_STRENGTH[c] * LOADINGS[c][r][1] * zs[c] for c in EFFECT_STRENGTH)
            out[r] = (rho0 * np.exp(drho + self.between[i, k, 0]), m0 * np.exp(dm + self.between[i, k, 1]))
        return out


def _population_draws(seed, table1_spread) -> _Draws:
    """Demographics, covariates, skin colours, σtr per site and between-subject BRDF offsets of the population.

    σtr and the offsets are drawn for n + 1 people, the last row unused: the streams of the population before
    2026-12-06 with its 150th person, so that the 149 subjects keep their draws (with or without the
    conditions, which changed every draw then)."""
    root = np.random.SeedSequence(seed)
    demo_seed, tr_seed, subj_seed = root.spawn(3)
    demo = _demographics(np.random.default_rng(demo_seed))
    n = len(demo)
    rng = np.random.default_rng(tr_seed)
    st = np.array([d[0] for d in demo])
    gender = np.array([d[1] for d in demo])
    age = np.array([d[2] for d in demo])
    z_cov = {
        "skin_type": _standardise(np.where(st == 1, 2, st)),
        "gender": _standardise(gender == "F"),
        "age": _standardise(age),
    }
    melanin = np.array([SKIN_TYPE_MELANIN[s] for s in st]) + MELANIN_SPREAD * rng.standard_normal(n)
    melanin -= 0.05 * (gender == "F")
    return _Draws(
        skin_type=st,
        gender=gender,
        age=age,
        z_cov=z_cov,
        melanin=melanin,
        base_rgb=skin_albedo(melanin),
        sigma_tr=_sigma_tr_draws(rng, n + 1, table1_spread),
        between=rng.standard_normal((n + 1, len(REGION_IDS), 2)) * BETWEEN_SUBJECT_CV,
        subject_seeds=subj_seed.spawn(n + len(CONDITIONS)),
    )


def condition_person(skin_type, gender, age) -> int:
    """Index of the subject also measured under the other conditions of §7: the type III man whose age is nearest
    34 (the first such), from the population's demographic draws.

    Parameters
    ----------
    skin_type, gender, age : array_like, shape (n,)
        Per subject: Fitzpatrick type (int), ``"M"`` or ``"F"``, age in years; at least one type III man.

    Returns
    -------
    int
        0-based index into the arrays.
    """
    st, g, a = (np.asarray(x) for x in (skin_type, gender, age))
    men = np.flatnonzero((st == 3) & (g == "M"))
    return int(men[np.argmin(np.abs(a[men] - 34))])


def _series_ids(draws):
    """``{condition: subject id}`` of the condition person's records other than normal."""
    sid = f"S{condition_person(draws.skin_type, draws.gender, draws.age) + 1:03d}"
    return {c: f"{sid}-{c}" for c in CONDITIONS if c != "normal"}


def _check_wanted(wanted, draws, conditions, one=None):
    """Raise unless every wanted id is an id of the population; ``one``: the parameter a single id was given as
    (named in the singular with the id), else the ids are ``subjects``."""
    if wanted is None:
        return
    n = len(draws.skin_type)
    series = set(_series_ids(draws).values()) if conditions else set()
    unknown = sorted(wanted - ({f"S{i + 1:03d}" for i in range(n)} | series))
    if unknown:
        ids = f"S001-S{n:03d}" + (f", {min(series)[:4]}-<condition>" if series else "")
        if one is not None:
            raise ValidationError(f"{one} must be an id of the population ({ids}), got {unknown[0]!r}")
        raise ValidationError(f"subjects must be ids of the population ({ids}), got unknown {unknown[:5]}")


def check_population_id(subject_id, seed: int = 2006, *, conditions: bool = True, name: str = "subject_id") -> str:
    """``subject_id`` if it is an id of the synthetic population drawn with ``seed``, else an error naming it.

    The ids :func:`synthesize_population` knows (``S001`` … ``S149``; with ``conditions``, the condition person's
    ``<id>-<condition>`` too), checked from the population's demographic draws alone (about 10 ms), before any
    subject is materialised.

    Parameters
    ----------
    subject_id : str
        The id to check.
    seed : int
        Seed of the population (≥ 0).
    conditions : bool
        Whether the condition person's records count (as :func:`synthesize_population`'s ``conditions``).
    name : str
        The parameter ``subject_id`` was given as, for the message.

    Returns
    -------
    str
        ``subject_id``.

    Raises
    ------
    ValidationError
        ``name must be an id of the population (S001-S149, S008-<condition>), got 'S999'``, or a bad ``seed``.
    """
    check_integer(seed, "seed", 0)
    if not isinstance(subject_id, str):
        raise ValidationError(f"{name} must be a subject id (a string), got {subject_id!r}")
    _check_wanted({subject_id}, _population_draws(seed, "std"), conditions, one=name)
    return subject_id


def _person_record(draws, i, sid, condition, region_map, texel_mm, freckle_fraction, seed):
    """Subject ``i`` of the population measured under ``condition``: its texture from its own stream (the same
    for every condition), its region means scaled by the condition's effect (``CONDITION_EFFECTS``)."""
    srng = np.random.default_rng(draws.subject_seeds[i])
    means = draws.region_means(i, {c: draws.z_cov[c][i] for c in draws.z_cov})
    freckled = bool(draws.skin_type[i] <= 3 and srng.uniform() < freckle_fraction / 0.57)
    n_moles = int(srng.poisson(1.0))
    gender = str(draws.gender[i])
    alb = albedo_map(
        region_map,
        draws.base_rgb[i],
        srng,
        texel_mm=texel_mm,
        freckles=freckled,
        moles=n_moles,
        condition=condition,
    )
    if condition != "normal":
        f_rho, f_m = CONDITION_EFFECTS[condition]
        means = {r: (v[0] * f_rho, v[1] * f_m) for r, v in means.items()}
    rho, m = _brdf_maps(region_map, means, srng, gender)
    meta = {
        "subject_id": sid,
        "person_id": f"S{i + 1:03d}",
        "age": int(draws.age[i]),
        "gender": gender,
        "skin_type": int(draws.skin_type[i]),
        "condition": condition,
    }
    return _make_subject(
        meta,
        region_map,
        alb,
        rho,
        m,
        draws.sigma_tr[i],
        seed=int(seed.generate_state(1)[0]),
        features={"freckles": freckled, "moles": n_moles, "melanin": float(draws.melanin[i])},
    )


def _normal_subjects(draws, region_map, texel_mm, freckle_fraction, wanted):
    """The subjects S001... of the population (those in ``wanted`` if given), each from its own stream."""
    out = []
    for i in range(len(draws.skin_type)):  # loop over subjects (each vectorised over texels)
        sid = f"S{i + 1:03d}"
        if wanted is None or sid in wanted:
            seed = draws.subject_seeds[i]
            out.append(_person_record(draws, i, sid, "normal", region_map, texel_mm, freckle_fraction, seed))
    return out


def _condition_subjects(draws, region_map, texel_mm, freckle_fraction, wanted):
    """:func:`condition_person` under the six conditions other than normal (§7), each from his texture."""
    k = condition_person(draws.skin_type, draws.gender, draws.age)
    n = len(draws.skin_type)
    out = []
    for j, (cond, sid) in enumerate(_series_ids(draws).items(), start=1):
        if wanted is None or sid in wanted:  # each record its own capture seed
            seed = draws.subject_seeds[n + j]
            out.append(_person_record(draws, k, sid, cond, region_map, texel_mm, freckle_fraction, seed))
    return out


def _make_subject(meta, region_map, alb, rho, m, sigma_tr_sites, *, seed, features):
    """A :class:`SubjectTruth` from its metadata and maps: Blinn-Phong truth, zeros off the face, site albedos."""
    face = region_map > 0
    bp_rho, bp_n = _bp_from_ts(rho, m)
    for a in (rho, m, bp_rho, bp_n):
        a[~face] = 0
    site_albedo = np.stack(
        [
            alb[region_map == 7].mean(axis=0),  # cheek
            alb[region_map == 2].mean(axis=0),  # forehead
            alb[face].mean(axis=0),  # neck: not mapped, the face average
        ]
    ).astype(np.float64)
    return SubjectTruth(
        **meta,
        region_map=region_map,
        albedo=alb,
        ts_rho_s=rho,
        ts_m=m,
        bp_rho_s=bp_rho,
        bp_exponent=bp_n,
        site_sigma_tr=np.asarray(sigma_tr_sites, float),
        site_albedo=site_albedo,
        seed=seed,
        features=features,
    )


def default_population(map_size: int = DEFAULT_MAP_SIZE, seed: int = DEFAULT_SEED) -> Population:
    """The embedded default population: :func:`synthesize_population` with its defaults.

    Parameters
    ----------
    map_size : int
        Side of the UV maps (default 48).
    seed : int
        Seed of every random draw (default 2006).

    Returns
    -------
    Population
    """
    return synthesize_population(seed=seed, map_size=map_size)

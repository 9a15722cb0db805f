"""Translucency from one image (Suzuki, Mukaigawa & Yagi; issue 13): speed, memory and the studies' figures.

* ``w_build`` — W of eq. 33 for 20,000 patches (4·10⁸ visible × lit pairs) at
  0.25 mm: time (untraced) and peak traced memory (from a second, traced run:
  tracemalloc slows it several fold) (requirement ≤ 30 s, ≤ 1 GB), and the
  ratio against the straightforward dense implementation (full distance matrix,
  eq. 25-27 per pair, ``np.add.at``) on the largest size the dense one holds
  comfortably here (3,000 patches, 9·10⁶ pairs; its m × m temporaries would need
  ~13 GB at 20,000).  Both run in the same process, one after the other.
* ``grid_fit`` — the eq. 36 grid search over Suzuki Table 2's 9,000 models
  (requirement ≤ 1 s), against a Python loop over the models (the same numpy
  profile per model).
* ``table3`` — Suzuki Table 3 on the pyramid (patch spacing ``spacing``, edge
  light, point-kernel truth): the paper's row, the paper's solve (pinv) and
  the default (monotone), printed side by side.
* ``noise`` — 1 % multiplicative radiance noise over 20 seeds with
  ``width="auto"``: largest errors, spread, interval coverage.
* ``continuous_surface`` — a flat plate of 1 mm patches lit over a half plane,
  its exitance by a quadrature of the surface (sub-patches of 1/``sub`` mm,
  Table 1's medium): how far each forward model (``self_term`` point,
  footprint, surface) is from it, and the fits at ``width="auto"`` of eq. 36
  (point, footprint) beside the dipole fitted through W with the surface self
  term (``method="exitance"``), against the truth (2.19, 0.0021); then, for
  each further medium of ``media``, the refined exitance + surface fit's
  relative errors in σ's and σa.
* ``exitance_refinement`` — 32 exitance fits of synthetic continuous surfaces
  (plates, the pyramid, contactless windows; surface self term, 0-3 % noise):
  how far the refinement of ``fit_exitance_grid`` ends from the cost's minimum
  (a Nelder-Mead polish), against the eigen form of G itself it replaced and
  against L-BFGS-B on the cost; errors against the truth; seconds.
* ``face_window_surface`` — the contactless cheek window of a subject (0.3 mm
  grid) rendered with the point and the surface self terms (no noise, no
  cut-off radius): how far apart they are on the lit patches, and the default
  estimator against exitance + surface on the surface render, per channel.
* ``contactless`` — σtr of cheek and forehead from one simulated image each for
  the default population's first ``n_subjects`` subjects: median relative error
  against the truth and against the contact-sensor fit (requirement ≤ 10 %).
* ``contactless_methods`` — the same study for the default estimator (monotone, point self term) and for
  exitance + surface over the first ``n_subjects`` subjects: median and largest error, the fits more than 10 %
  off, interval coverage.
* ``contactless_population_2048`` — seconds and traced peak memory of
  ``contactless_population`` writing back one ``size``² subject with ``cameras``
  micro-normal cameras (``bench_export.representative_subject``): the
  micro-normals stay on disk and are copied band by band.
"""

from __future__ import annotations

import time
import tracemalloc
import warnings

import numpy as np

from facestats.errors import QuantisationWarning


def _points(m, seed=0):
    """m patch centres on a 100 × 100 mm sheet with gentle relief (a surface, not a volume)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 100, (m, 2))
    z = 5 * np.sin(xy[:, 0] / 15) * np.cos(xy[:, 1] / 20)
    return np.column_stack([xy, z]), rng.uniform(0.2, 1.0, m)


def _dense_w(points, weights, width):
    """The straightforward implementation: the full m × m distance matrix and np.add.at (eq. 25-27, 33)."""
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    n = int(np.floor(d.max() / width)) + 2
    x = d / width
    i = x.astype(np.int64)
    t = x - i
    w = np.zeros((points.shape[0], n))
    jj = np.broadcast_to(np.arange(points.shape[0])[:, None], d.shape)
    np.add.at(w, (jj, i), weights[None, :] * (1 - t))
    np.add.at(w, (jj, i + 1), weights[None, :] * t)
    return w


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _peak(fn):
    """Peak traced memory of ``fn()`` in bytes, from a run of its own: tracemalloc slows allocation-heavy code
    several fold (36.5 s instead of 7.8 s for W at 20,000 patches), so timings are taken untraced."""
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def bench_w_build(m=20_000, width=0.25, dense_m=3_000):
    from facestats.model.fitting.quantised import quantised_system

    p, c = _points(m)
    big, t_big = _timed(lambda: quantised_system(p, c, np.arange(m), width=width))
    peak_big = _peak(lambda: quantised_system(p, c, np.arange(m), width=width))
    area = np.full(m, 100.0 * 100.0 / m)  # the sheet shared out: 0.5 mm² each at 20,000
    _, t_surface = _timed(lambda: quantised_system(p, c, np.arange(m), width=width, areas=area, near=True))
    ps, cs = _points(dense_m, seed=1)
    small, t_small = _timed(lambda: quantised_system(ps, cs, np.arange(dense_m), width=width))
    ref, t_dense = _timed(lambda: _dense_w(ps, cs, width))
    peak_small = _peak(lambda: quantised_system(ps, cs, np.arange(dense_m), width=width))
    peak_dense = _peak(lambda: _dense_w(ps, cs, width))
    assert np.allclose(small.matrix, ref[:, : small.n_levels], rtol=1e-9, atol=1e-9)
    return {
        "seconds_20k": t_big,
        "pairs_20k": float(m) * m,
        "peak_MB_20k": peak_big / 2**20,
        "levels_20k": big.n_levels,
        "seconds_20k_surface_self_term": t_surface,
        "target_s": 30.0,
        "target_MB": 1024.0,
        f"streamed_s_{dense_m}": t_small,
        f"dense_s_{dense_m}": t_dense,
        "speedup_vs_dense": t_dense / t_small,
        f"streamed_peak_MB_{dense_m}": peak_small / 2**20,
        f"dense_peak_MB_{dense_m}": peak_dense / 2**20,
    }


def bench_grid_fit(n_levels=150, loop_models=300):
    from facestats.model.dipole import dipole_profile
    from facestats.model.fitting.profile_grid import TABLE2_GRID, fit_profile_grid

    d = np.linspace(0, 40, n_levels)
    r = dipole_profile(d, 2.19, 0.0021, 1.3)
    fit_profile_grid(d, r, eta=1.3)  # warm up (imports)
    t0 = time.perf_counter()
    fit = fit_profile_grid(d, r, eta=1.3)
    t_grid = time.perf_counter() - t0
    y = np.log(r)
    t0 = time.perf_counter()
    for k in range(loop_models):  # the baseline: one model at a time
        s = TABLE2_GRID.sigma_s_prime[k % 300]
        a = TABLE2_GRID.sigma_a[k % 30]
        float(np.sum((y - np.log(dipole_profile(d, s, a, 1.3))) ** 2))
    t_loop = (time.perf_counter() - t0) * 9000 / loop_models
    return {
        "grid_fit_s": t_grid,
        "models": 9000,
        "levels": n_levels,
        "target_s": 1.0,
        "loop_s_extrapolated": t_loop,
        "speedup": t_loop / t_grid,
        "found": f"({fit.sigma_s_prime}, {fit.sigma_a})",
    }


def bench_table3(spacing=1.8, widths=(8.0, 4.0, 2.0, 1.0, 0.5, 0.25, 0.125, 0.0625, 0.03125)):
    from facestats.acquire.synthetic.scenes import pyramid_scene
    from facestats.pipeline.suzuki_studies import format_table3, render_scene, table3

    t0 = time.perf_counter()
    r = render_scene(pyramid_scene(spacing, "edge"))
    rows = table3(r, widths=widths)
    print(format_table3(rows))
    row = next((x for x in rows if x["width"] == 0.25), rows[0])
    return {
        "row_025_monotone": str(row["monotone"]),
        "row_025_pinv": str(row["pinv"]),
        "seconds": time.perf_counter() - t0,
    }


def bench_noise(spacing=1.8, seeds=20):
    from facestats.acquire.synthetic.scenes import pyramid_scene
    from facestats.pipeline.suzuki_studies import noise_study, render_scene

    t0 = time.perf_counter()
    st = noise_study(render_scene(pyramid_scene(spacing, "edge")), noise=0.01, seeds=seeds, width="auto")
    return dict(st.summary(), width_mm=float(st.widths[0]), seconds=time.perf_counter() - t0)


def bench_continuous_surface(n=41, sub=8, media=((0.5, 0.0005), (1.0, 0.001), (2.9, 0.0029))):
    from facestats.acquire.synthetic.subsurface import half_lit_plate, render_exitance
    from facestats.model.fitting import fit_scattering_image

    truth = (2.19, 0.0021)
    centres, areas, c, surface = half_lit_plate(*truth, n=n, sub=sub)
    lit = c > 0
    out = {}
    for term in ("point", "footprint", "surface"):
        l = render_exitance(centres, areas, c, *truth, radius=np.inf, self_term=term)
        out[f"render_{term}_median_lit_error"] = float(np.median(l[lit] / surface[lit] - 1))
    for term, method in (("point", "monotone"), ("footprint", "monotone"), ("surface", "exitance")):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QuantisationWarning)
            fit, dt = _timed(
                lambda: fit_scattering_image(centres, areas, c, surface, width="auto", self_term=term, method=method)
            )
        out[f"{term}_{method}"] = f"({fit.sigma_s_prime}, {fit.sigma_a}) at {fit.width:.3g} mm in {dt:.2f} s"
    out["truth"] = str(truth)
    for medium in media:  # other media: the refined exitance + surface fit against the truth
        centres, areas, c, surface = half_lit_plate(*medium, n=n, sub=sub)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QuantisationWarning)
            fit = fit_scattering_image(
                centres, areas, c, surface, width="auto", self_term="surface", method="exitance", refine=True
            )
        out[f"surface_exitance_refined_{medium[0]}_{medium[1]}_rel_err"] = (
            f"({fit.sigma_s_prime / medium[0] - 1:+.4f}, {fit.sigma_a / medium[1] - 1:+.4f})"
        )
    return out


def _exitance_cases(plate_media, plate_n, plate_sub, plate_width, pyramid_widths, pyramid_noise, faces, face_width):
    """Exitance fits of synthetic continuous surfaces (surface self term, its W unmerged at a fixed width): yields
    (label, truth (σ's, σa), levels, G, g, n rows, grid, η), the normal equations as ``method="exitance"`` fits them.

    Plates of ``plate_n``² 1 mm patches lit over a half plane (exitance by a quadrature of 1/``plate_sub`` mm), each
    medium noise-free and with 1 % noise (its grid: Suzuki Table 2 when the medium lies inside it, else the skin
    grid); Table 1's medium on the pyramid of 1.8 mm patches at each width of ``pyramid_widths`` with each
    (noise, seed) of ``pyramid_noise``; the contactless windows of ``faces`` ((subject, site, light, noise)), R, G
    and B, rendered with the surface self term at the subject's site coefficients (η 1.38, skin grid).
    """
    from facestats.acquire.lights import patch_irradiance
    from facestats.acquire.scene import camera_sees
    from facestats.acquire.synthetic.population import default_population
    from facestats.acquire.synthetic.scenes import face_site_scene, pyramid_scene
    from facestats.acquire.synthetic.subsurface import half_lit_plate, render_exitance
    from facestats.core.conventions import SITES
    from facestats.model.fitting.profile_grid import TABLE2_GRID
    from facestats.model.fitting.quantised import normal_equations, quantised_system, self_term_keywords
    from facestats.pipeline.contactless import ETA_SKIN, SKIN_GRID
    from facestats.pipeline.suzuki_studies import render_scene

    def system(p, area, c, rows, width):
        return quantised_system(p, c * area, rows, width=width, **self_term_keywords("surface", area))

    def case(label, truth, sys, l, grid, eta):
        neq = normal_equations(sys, np.maximum(l, 0), weighted=True)
        return label, truth, sys.levels, neq.gram, neq.rhs, neq.n_rows, grid, eta

    for medium in plate_media:  # noise-free and 1 % noise
        centres, areas, c, l = half_lit_plate(*medium, n=plate_n, sub=plate_sub)
        inside = TABLE2_GRID.sigma_s_prime[-1] >= medium[0] and TABLE2_GRID.sigma_a[-1] >= medium[1]
        w = system(centres, areas, c, np.arange(len(c)), plate_width)
        for noise in (0.0, 0.01):
            noisy = l * (1 + noise * np.random.default_rng(1).standard_normal(l.size))
            yield case(f"plate {medium} noise {noise}", medium, w, noisy, TABLE2_GRID if inside else SKIN_GRID, 1.3)
    if pyramid_widths:
        r = render_scene(pyramid_scene(1.8), self_term="surface")
        rows = np.nonzero(r.visible)[0]
        for width in pyramid_widths:
            w = system(r.patches.centre, r.patches.area, r.irradiance, rows, width)
            for noise, seed in pyramid_noise:
                noisy = r.exitance[rows] * (1 + noise * np.random.default_rng(seed).standard_normal(rows.size))
                truth = (r.sigma_s_prime, r.sigma_a)
                yield case(f"pyramid {width} mm noise {noise} seed {seed}", truth, w, noisy, TABLE2_GRID, r.eta)
    population = default_population() if faces else None
    for subject, site, light, noise in faces:
        sp, sa = population[subject].site_scattering
        k = list(SITES).index(site)
        scene = face_site_scene(site, light, spacing=0.3)
        p = scene.patches
        c = patch_irradiance(p, scene.lights, eta=ETA_SKIN)
        rows = np.nonzero(camera_sees(scene.camera, p))[0]
        for ch, name in enumerate("RGB"):  # one W per channel: the projector is white, but c is per channel
            truth = (float(sp[k, ch]), float(sa[k, ch]))
            l = render_exitance(p.centre, p.area, c[:, ch], *truth, eta=ETA_SKIN, radius=np.inf, self_term="surface")
            l = l[rows] * (1 + noise * np.random.default_rng(ch).standard_normal(rows.size))
            w = system(p.centre, p.area, c[:, ch], rows, face_width)
            yield case(f"{subject} {site} {light} {name} noise {noise}", truth, w, l, SKIN_GRID, ETA_SKIN)


def _eigen_refinement(levels, gram, rhs, grid, eta, start):
    """The exitance refinement before 2026-12-07, a baseline: least squares in (ln σ's, ln σa) from ``start`` on
    ‖Λ^½ Vᵀ R − Λ^-½ Vᵀ g‖², the eigenpairs (Λ, V) of G itself (not equilibrated) with λ > 10⁻¹³ λmax; returns
    (σ's, σa) in mm⁻¹."""
    from scipy.optimize import least_squares

    from facestats.model.dipole import dipole_profile

    lam, vec = np.linalg.eigh(gram)
    keep = lam > lam.max() * 1e-13
    root, v = np.sqrt(lam[keep]), vec[:, keep]
    vg = v.T @ rhs
    lo = np.log([grid.sigma_s_prime[0], grid.sigma_a[0]])
    hi = np.log([grid.sigma_s_prime[-1], grid.sigma_a[-1]])
    sol = least_squares(
        lambda x: root * (v.T @ dipole_profile(levels, *np.exp(x), eta)) - vg / root,
        np.clip(np.log(start), lo, hi),
        bounds=(lo, hi),
        xtol=1e-12,
        ftol=1e-14,
    )
    return tuple(np.exp(sol.x))


def _direct_refinement(cost, grid, start):
    """An alternative the review proposed: L-BFGS-B on the cost itself in (ln σ's, ln σa) from ``start``, within the
    grid's range (central-difference gradient); returns (σ's, σa) in mm⁻¹."""
    from scipy.optimize import minimize

    lo = np.log([grid.sigma_s_prime[0], grid.sigma_a[0]])
    hi = np.log([grid.sigma_s_prime[-1], grid.sigma_a[-1]])
    sol = minimize(
        lambda x: cost(*np.exp(x)),
        np.clip(np.log(start), lo, hi),
        method="L-BFGS-B",
        jac="3-point",
        bounds=list(zip(lo, hi)),
        options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 1000},
    )
    return tuple(np.exp(sol.x))


def bench_exitance_refinement(
    plate_media=((2.19, 0.0021), (0.5, 0.0005), (1.0, 0.001), (2.9, 0.0029), (1.2, 0.02), (2.5, 0.3)),
    plate_n=41,
    plate_sub=8,
    plate_width=0.1,
    pyramid_widths=(0.25, 0.12),
    pyramid_noise=((0.0, 0), (0.01, 0), (0.01, 1), (0.03, 2)),
    faces=(
        ("S001", "cheek", "stripe", 0.0),
        ("S002", "forehead", "spot", 0.01),
        ("S003", "cheek", "spot", 0.01),
        ("S004", "forehead", "stripe", 0.0),
    ),
    face_width=0.0775,
):
    """The exitance fit's refinement (``fit_exitance_grid(refine=True)``: least squares over the eigenpairs of the
    equilibrated G) against the eigen form of G itself it replaced (``eigen``; ``eigen_kept`` after the rule that
    keeps the grid model when the cost rises) and L-BFGS-B on the cost (``direct``), on :func:`_exitance_cases`.
    Each case's minimum is a Nelder-Mead polish of the best optimum found, on the same cost; a miss is a cost above
    it by more than 10⁻⁶ (relative); ``dlog`` is the largest distance to it in ln σ's or ln σa."""
    from scipy.optimize import minimize

    from facestats.model.dipole import dipole_profile
    from facestats.model.fitting.profile_grid import fit_exitance_grid

    cases = _exitance_cases(
        plate_media, plate_n, plate_sub, plate_width, pyramid_widths, pyramid_noise, faces, face_width
    )
    names = ("grid", "refined", "eigen", "eigen_kept", "direct")
    rows = []
    for label, truth, d, g, b, n, grid, eta in cases:  # one exitance fit per case

        def cost(s, a):
            m = dipole_profile(d, s, a, eta)
            return max(float(m @ g @ m - 2 * (m @ b) + n), 0.0)

        coarse, t_grid = _timed(lambda: fit_exitance_grid(d, g, b, n, grid=grid, eta=eta))
        fit, t_fit = _timed(lambda: fit_exitance_grid(d, g, b, n, grid=grid, eta=eta, refine=True))
        start = (coarse.sigma_s_prime, coarse.sigma_a)
        eigen, t_eigen = _timed(lambda: _eigen_refinement(d, g, b, grid, eta, start))
        found = {
            "grid": start,
            "refined": (fit.sigma_s_prime, fit.sigma_a),
            "eigen": eigen,
            "eigen_kept": eigen if cost(*eigen) <= cost(*start) else start,
            "direct": _direct_refinement(cost, grid, start),
        }
        best = min(found.values(), key=lambda x: cost(*x))
        polish = minimize(
            lambda x: cost(*np.exp(x)),
            np.log(best),
            method="Nelder-Mead",
            options={"xatol": 1e-11, "fatol": 1e-15, "maxiter": 4000, "maxfev": 4000},
        )
        minimum = np.exp(polish.x) if polish.fun < cost(*best) else np.asarray(best)
        c_min = cost(*minimum)
        tr = np.sqrt(3 * truth[1] * (truth[1] + truth[0]))
        diagonal = np.diag(g)[np.diag(g) > 0]
        row = {"label": label, "levels": d.size, "diag_decades": float(np.log10(diagonal.max() / diagonal.min()))}
        for name in names:  # each method's optimum against the minimum and the truth
            s, a = found[name]
            row[name] = {
                "excess": cost(s, a) / max(c_min, 1e-300) - 1,
                "dlog": float(np.abs(np.log([s, a]) - np.log(minimum)).max()),
                "s_err": s / truth[0] - 1,
                "a_err": a / truth[1] - 1,
                "tr_err": float(np.sqrt(3 * a * (a + s))) / tr - 1,
            }
        row["seconds_refine"] = t_fit - t_grid
        row["seconds_eigen"] = t_eigen
        rows.append(row)
    for r in rows:  # the cases, one line each
        print(
            f"{r['label']:38s} {r['levels']:4d} levels, diag(G) over {r['diag_decades']:3.0f} decades | "
            + " | ".join(f"{k} {r[k]['excess']:+.0e} σ's {r[k]['s_err']:+.4f}" for k in names)
        )
    out = {"cases": len(rows)}
    for name in names:  # the headline figures per method
        excess = np.array([r[name]["excess"] for r in rows])
        out[f"{name}_misses"] = int((excess > 1e-6).sum())
        out[f"{name}_max_excess"] = float(excess.max())
        out[f"{name}_max_dlog"] = max(r[name]["dlog"] for r in rows)
        out[f"{name}_median_abs_tr_err"] = float(np.median([abs(r[name]["tr_err"]) for r in rows]))
        out[f"{name}_max_abs_tr_err"] = max(abs(r[name]["tr_err"]) for r in rows)
        out[f"{name}_max_abs_s_err"] = max(abs(r[name]["s_err"]) for r in rows)
        out[f"{name}_max_abs_a_err"] = max(abs(r[name]["a_err"]) for r in rows)
    out["diag_decades"] = f"{min(r['diag_decades'] for r in rows):.0f}-{max(r['diag_decades'] for r in rows):.0f}"
    out["max_levels"] = max(r["levels"] for r in rows)
    out["seconds_refine_median"] = float(np.median([r["seconds_refine"] for r in rows]))
    out["seconds_refine_max"] = max(r["seconds_refine"] for r in rows)
    out["seconds_eigen_median"] = float(np.median([r["seconds_eigen"] for r in rows]))
    out["seconds_eigen_max"] = max(r["seconds_eigen"] for r in rows)
    return out


def bench_face_window_surface(subject="S001", spacing=0.3):
    from facestats.acquire.lights import patch_irradiance
    from facestats.acquire.scene import camera_sees
    from facestats.acquire.synthetic.population import default_population
    from facestats.acquire.synthetic.scenes import face_site_scene
    from facestats.acquire.synthetic.subsurface import render_exitance
    from facestats.core.conventions import SITES
    from facestats.model.fitting import fit_scattering_image
    from facestats.pipeline.contactless import ETA_SKIN, SKIN_GRID

    sp, sa = default_population()[subject].site_scattering
    k = list(SITES).index("cheek")
    scene = face_site_scene("cheek", "stripe", spacing=spacing)
    p = scene.patches
    c = patch_irradiance(p, scene.lights, eta=ETA_SKIN)
    seen = camera_sees(scene.camera, p)
    out = {"patches": len(p), "median_area_mm2": float(np.median(p.area))}
    for ch, name in enumerate("RGB"):  # three channels
        medium = (sp[k, ch], sa[k, ch])
        point, surface = (
            render_exitance(p.centre, p.area, c[:, ch], *medium, eta=ETA_SKIN, radius=np.inf, self_term=term)
            for term in ("point", "surface")
        )
        lit = c[:, ch] > 0
        out[f"{name}_surface_vs_point_lit_median"] = float(np.median(surface[lit] / point[lit] - 1))
        for term, method in (("point", "monotone"), ("surface", "exitance")):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", QuantisationWarning)
                fit = fit_scattering_image(
                    p.centre, p.area, c[:, ch], surface, width="auto", visible=seen, eta=ETA_SKIN,
                    grid=SKIN_GRID, refine=True, self_term=term, method=method,
                )  # fmt: skip
            out[f"{name}_{term}_{method}_rel_err"] = (
                f"({fit.sigma_s_prime / medium[0] - 1:+.4f}, {fit.sigma_a / medium[1] - 1:+.4f})"
            )
    return out


def _contactless_studies(n_subjects, spacing, sites, variants, *, progress=False):
    """``contactless_study`` (stripe light, 1 % noise) of the embedded store's first ``n_subjects`` subjects against
    the default population's truth, once per dict of further options in ``variants``.

    Returns
    -------
    ids : list of str
        The subjects.
    runs : list of (pandas.DataFrame, float)
        Per variant, the study's table and its seconds.
    """
    import facestats
    from facestats.acquire.synthetic.population import default_population
    from facestats.pipeline.contactless import contactless_study

    pop = default_population()
    runs = []
    with facestats.open_store() as store, warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        ids = [s for s in store.ids() if s.startswith("S")][: int(n_subjects)]
        for options in variants:
            t0 = time.perf_counter()
            df = contactless_study(ids, store, pop, spacing=spacing, sites=tuple(sites), progress=progress, **options)
            runs.append((df, time.perf_counter() - t0))
    return ids, runs


def _interval_coverage(df):
    """Share of a contactless study's rows whose interval [image_low, image_high] holds the truth."""
    return float(((df["image_low"] <= df["truth"]) & (df["truth"] <= df["image_high"])).mean())


def bench_contactless(n_subjects=20, spacing=0.3, sites=("cheek", "forehead")):
    ids, [(df, seconds)] = _contactless_studies(n_subjects, spacing, sites, [{}], progress=True)
    err = df["error_vs_truth"].abs()
    return {
        "median_rel_error_vs_truth": float(err.median()),
        "max_rel_error_vs_truth": float(err.max()),
        "median_rel_error_vs_sensor": float(df["error_vs_sensor"].abs().median()),
        "target": 0.10,
        "interval_coverage": _interval_coverage(df),
        "subjects": len(ids),
        "seconds_per_subject": seconds / max(len(ids), 1),
    }


def bench_contactless_methods(
    n_subjects=10, spacing=0.3, sites=("cheek", "forehead"), methods=(("monotone", "point"), ("exitance", "surface"))
):
    """The contactless study (``contactless_study``, stripe, 1 % noise) per estimator over the same subjects: median
    and largest |relative error| of σtr against the truth, the (site, channel) fits more than 10 % off (count and
    names), interval coverage."""
    variants = [{"method": method, "self_term": self_term} for method, self_term in methods]
    ids, runs = _contactless_studies(n_subjects, spacing, sites, variants)
    out = {}
    for (method, self_term), (df, seconds) in zip(methods, runs):
        err = df["error_vs_truth"].abs()
        off = df[err > 0.10]
        key = f"{method}+{self_term}"
        out[f"{key}_median_rel_error"] = float(err.median())
        out[f"{key}_max_rel_error"] = float(err.max())
        out[f"{key}_fits_off_10pct"] = int(off.shape[0])
        out[f"{key}_off"] = " ".join(f"{r.subject}/{r.site}/{r.channel}" for r in off.itertuples()) or "-"
        out[f"{key}_interval_coverage"] = _interval_coverage(df)
        out[f"{key}_seconds_per_subject"] = seconds / max(len(ids), 1)
    out["fits_per_method"] = len(ids) * len(sites) * 3
    return out


def bench_contactless_population(size=2048, cameras=16, spacing=0.3):
    import tempfile

    from bench_export import representative_subject

    import facestats
    from facestats.acquire.synthetic.population import default_population
    from facestats.pipeline.contactless import contactless_population

    source = representative_subject(size, cameras=cameras)
    subject_mb = sum(v.nbytes for v in source.variables.values()) / 2**20
    micro = source["micro_normal"].values.copy()
    pop = default_population()
    with tempfile.TemporaryDirectory() as d, warnings.catch_warnings():
        warnings.simplefilter("ignore", QuantisationWarning)
        with facestats.open_store(f"{d}/s.zarr", mode="a") as store:
            store.write_subject(source)
            del source
            tracemalloc.start()
            t = time.perf_counter()
            contactless_population(store, ["S001"], pop, spacing=spacing, progress=False)
            wall = time.perf_counter() - t
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            back = store.subject("S001")
    return {
        "peak_over_subject": peak / subject_mb,
        "seconds": wall,
        "peak_MB": peak,
        "subject_MB": subject_mb,
        "micro_normals_copied_exactly": bool(np.array_equal(back["micro_normal"].values, micro)),
        "image_sigma_tr_finite": bool(np.isfinite(back["image_sigma_tr"].values[:2]).all()),
    }


BENCHMARKS = [
    ("w_build", bench_w_build),
    ("grid_fit", bench_grid_fit),
    ("table3", bench_table3),
    ("noise", bench_noise),
    ("continuous_surface", bench_continuous_surface),
    ("exitance_refinement", bench_exitance_refinement),
    ("face_window_surface", bench_face_window_surface),
    ("contactless", bench_contactless),
    ("contactless_methods", bench_contactless_methods),
    ("contactless_population_2048", bench_contactless_population),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "w_build": {"m": 400, "width": 1.0, "dense_m": 200},
    "grid_fit": {"n_levels": 20, "loop_models": 10},
    "table3": {"spacing": 6.0, "widths": (2.0,)},
    "noise": {"spacing": 6.0, "seeds": 2},
    "continuous_surface": {"n": 15, "sub": 2, "media": ((1.0, 0.001),)},
    "exitance_refinement": {
        "plate_media": ((1.0, 0.6),),
        "plate_n": 15,
        "plate_sub": 2,
        "plate_width": 0.5,
        "pyramid_widths": (),
        "faces": (),
    },
    "face_window_surface": {"spacing": 1.0},
    "contactless": {"n_subjects": 1, "spacing": 0.8, "sites": ("cheek",)},
    "contactless_methods": {"n_subjects": 1, "spacing": 0.8, "sites": ("cheek",)},
    "contactless_population_2048": {"size": 64, "cameras": 2, "spacing": 0.8},
}

"""The ``facestats analyze`` command: population figures and their numbers (Weyrich et al. 2006 §5.4, §7).

Usage::

    facestats analyze pca|cca|scatter|translucency|conditions|models|posterior|all [--store PATH] [--out DIR]
                      [--format png|svg] [options]

Each action makes one call of :mod:`facestats.analysis`, draws the result
with :mod:`facestats.analysis.plots`, writes ``<action>.png`` (or ``.svg``)
and ``<action>.json`` (the result's ``to_dict()``) into ``--out`` and prints
the result's ``to_text()``: a short summary beside the published values of
:mod:`facestats.core.published`.  ``all`` runs
every action but ``posterior``.  Heavy modules are imported inside the
handlers, so registering the command costs nothing at start-up.

JSON outputs
------------
Every file is a JSON object with the keys ``action``, ``facestats_version``,
``store`` (the store's label: ``"default"`` or its path) and ``figure`` (the
file name of the figure written beside it), then the keys of the result's
``to_dict()``, documented there (conventions: :mod:`facestats.analysis.serialize`):

``pca.json`` (Fig. 15)
    :meth:`facestats.analysis.pca.RegionPCA.to_dict`
``cca.json`` (Fig. 16)
    :meth:`facestats.analysis.cca.CCAResult.to_dict`
``scatter.json`` (Fig. 14)
    :meth:`facestats.analysis.scatter.AbsorptionScattering.to_dict`
``translucency.json`` (Table 1 and §5.4)
    :meth:`facestats.analysis.translucency.TranslucencyTable.to_dict`
``conditions.json`` (§7)
    :meth:`facestats.analysis.conditions.ConditionDifferences.to_dict`
``models.json`` (§5.3, Fig. 7)
    :meth:`facestats.analysis.models.ModelErrors.to_dict`
``posterior.json`` (§5.4 with uncertainty)
    :meth:`facestats.analysis.posterior.profile.SigmaPosterior.to_dict`
``posterior_population.json`` (``posterior --population``)
    :meth:`facestats.analysis.posterior.hierarchical.PopulationSigmaTr.to_dict`

The printed summaries are the results' ``to_text()``.
"""

from __future__ import annotations

import json
import sys
import warnings

from facestats.cli.options import add_store_option, ascii_int, named_options, non_empty, open_store_option
from facestats.errors import ValidationError

__all__ = ["add_analyze", "ACTIONS", "BATCH_ACTIONS"]

#: Sub-actions of ``facestats analyze``.
ACTIONS = ("pca", "cca", "scatter", "translucency", "conditions", "models", "posterior", "all")
#: What ``all`` runs (every analysis but the per-profile posterior).
BATCH_ACTIONS = ("pca", "cca", "scatter", "translucency", "conditions", "models")

# -- the actions ------------------------------------------------------------------
# Each returns (figure, JSON document, summary text).


def _pca(store, args):
    from facestats.analysis import region_pca
    from facestats.analysis.plots import plot_region_pca

    res = region_pca(store, model=args.model)
    return plot_region_pca(res), res.to_dict(), res.to_text()


def _cca(store, args):
    from facestats.analysis import brdf_cca
    from facestats.analysis.plots import plot_cca

    if args.permutations < 0:
        raise ValidationError(f"--permutations must be >= 0, got {args.permutations}")
    res = brdf_cca(store, model=args.model, n_permutations=args.permutations, seed=args.seed)
    return plot_cca(res), res.to_dict(), res.to_text()


def _scatter(store, args):
    from facestats.analysis import absorption_scattering
    from facestats.analysis.plots import plot_absorption_scattering

    res = absorption_scattering(store, site=args.site)
    return plot_absorption_scattering(res), res.to_dict(), res.to_text()


def _translucency(store, args):
    from facestats.analysis import translucency_table
    from facestats.analysis.plots import plot_translucency

    res = translucency_table(store)
    return plot_translucency(res), res.to_dict(), res.to_text()


def _conditions(store, args):
    from facestats.analysis import condition_differences
    from facestats.analysis.plots import plot_conditions

    res = condition_differences(store, model=args.model)
    return plot_conditions(res), res.to_dict(), res.to_text()


def _models(store, args):
    from facestats.analysis import model_errors
    from facestats.analysis.plots import plot_model_errors

    res = model_errors(store, progress=True)  # hidden by FACESTATS_PROGRESS=0
    return plot_model_errors(res), res.to_dict(), res.to_text()


def _posterior(store, args):
    from facestats.analysis import store_sigma_posterior
    from facestats.analysis.plots import plot_site_posterior
    from facestats.errors import ConvergenceWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        post = store_sigma_posterior(store, args.subject, args.site, std=args.noise, seed=args.seed)
    for w in caught:
        if issubclass(w.category, ConvergenceWarning):
            print(f"facestats: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return plot_site_posterior(post), post.to_dict(), post.to_text()


def _population_posterior(store, args):
    from facestats.analysis import population_sigma_tr
    from facestats.analysis.plots import plot_population_sigma_tr

    res = population_sigma_tr(store, seed=args.seed)
    return plot_population_sigma_tr(res), res.to_dict(), res.to_text()


_HANDLERS = {
    "pca": _pca,
    "cca": _cca,
    "scatter": _scatter,
    "translucency": _translucency,
    "conditions": _conditions,
    "models": _models,
}


# -- writing ------------------------------------------------------------------------
def _out_dir(args):
    """``--out``, checked before any work (created when the files are written, all at the end): without
    ``--overwrite``, none of the files the action(s) may write may exist already."""
    from facestats.core.outputs import check_names_free, check_output_dir

    out = check_output_dir(args.out, "--out")
    if not args.overwrite:
        if args.action == "posterior":
            names = ("posterior_population",) if args.population else ("posterior",)
        else:
            names = BATCH_ACTIONS if args.action == "all" else (args.action,)
        files = [f for n in names for f in (f"{n}.{args.format}", f"{n}.json")]
        check_names_free(out, files, "--out", "this analysis's files")
    return out


def _write(files, name, fig, doc, fmt, store):
    """Write ``name.<fmt>`` and ``name.json`` (the header keys, then ``doc``, JSON-ready) into the
    :class:`~facestats.core.outputs.OutputSet` ``files``; return their final paths."""

    from facestats.core.version import __version__

    figure, path = files.directory / f"{name}.{fmt}", files.directory / f"{name}.json"
    fig.savefig(files.path(figure.name), format=fmt, dpi=150)
    head = {"action": name, "facestats_version": __version__, "store": store.label, "figure": figure.name}
    with open(files.path(path.name), "w", encoding="utf-8") as f:
        json.dump({**head, **doc}, f, indent=2, allow_nan=False)
        f.write("\n")
    return figure, path


def _summary(text, files) -> str:
    return text + "\nwrote " + ", ".join(str(f) for f in files)


def _cmd_analyze(args) -> int:
    from facestats.core.outputs import OutputSet, check_apart

    out = _out_dir(args)
    report = []
    with open_store_option(args.store) as store:
        check_apart(out, store.path, "--out")  # before OutputSet creates any folder
        with OutputSet(out) as files, named_options(seed="--seed", site="--site", subject_id="--subject"):
            _run_actions(args, store, files, report)  # every file or none; errors name the options
    print("\n\n".join(report))  # once the files are in place: "wrote" is then true
    return 0


def _run_actions(args, store, files, report) -> None:
    """Run the action(s) of ``args``, writing into the OutputSet ``files``; append each summary to ``report``."""
    from facestats.errors import InsufficientDataError

    if args.action == "posterior":
        if args.population:
            if args.subject or args.site or args.noise != "model":
                raise ValidationError(
                    "posterior --population takes no --subject, --site or --noise stored (it works on each subject's "
                    "fitted sigma_tr, whose spread within a skin type holds the measurement noise)"
                )
            name, handler = "posterior_population", _population_posterior
        else:
            name, handler = "posterior", _posterior
        fig, doc, text = handler(store, args)
        report.append(_summary(text, _write(files, name, fig, doc, args.format, store)))
        return
    for action in BATCH_ACTIONS if args.action == "all" else (args.action,):
        try:
            fig, doc, text = _HANDLERS[action](store, args)
        except InsufficientDataError as exc:
            # ``all`` on a store that cannot support an analysis (too few subjects for the CCA, no condition
            # series, no maps, no sensor data as in an imported MERL store): skip it and say why. Bad options
            # and bad data are other errors: they stop the command.
            if args.action == "all":
                report.append(f"{action}: skipped ({exc})")
                continue
            raise
        report.append(_summary(text, _write(files, action, fig, doc, args.format, store)))


# -- registration -----------------------------------------------------------------
def _common(p, model=False):
    add_store_option(p)
    p.add_argument("--out", default=".", metavar="DIR", help="output directory (created if missing; default: .)")
    p.add_argument("--format", choices=("png", "svg", "pdf"), default="png", help="figure format (default png)")
    p.add_argument("--overwrite", action="store_true", help="replace this analysis's files in --out")
    if model:
        p.add_argument(
            "--model",
            choices=("ts", "bp"),
            default="ts",
            help="specular model: ts = Torrance-Sparrow (rho_s, m), as the paper; bp = Blinn-Phong (rho_s, n)",
        )


def _permutations(p):
    p.add_argument(
        "--permutations",
        type=ascii_int,
        default=999,
        metavar="N",
        help="permutations of the CCA permutation test (default 999; 0 skips it)",
    )
    p.add_argument("--seed", type=ascii_int, default=0, help="seed of the permutations (default 0)")


def add_analyze(subparsers):
    """Register ``facestats analyze`` and its actions.

    Parameters
    ----------
    subparsers : argparse sub-parsers action
        What ``ArgumentParser.add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    argparse.ArgumentParser
        The ``analyze`` parser; every action sets ``func`` to its handler, which
        returns the exit status (errors raise :class:`facestats.FacestatsError`).
    """
    p = subparsers.add_parser(
        "analyze",
        help="population analysis: Fig. 14-16, Table 1, condition differences, sigma posteriors (PNG/SVG + JSON)",
        description=(
            "Population analysis of a parameter store (Weyrich et al. 2006 §5.4 and §7). Each action writes "
            "ACTION.png (or .svg) and ACTION.json (the numbers) into --out and prints a summary beside the "
            "published values; 'all' runs every action but 'posterior'."
        ),
    )
    sub = p.add_subparsers(title="actions", metavar="ACTION", dest="action", required=True)
    a = sub.add_parser(
        "pca",
        help="region PCA ellipses of the specular parameters (Fig. 15)",
        description="PCA of the (rho_s, m) samples of every face region over the subjects measured "
        "under normal conditions; ellipses at ±1 sd (Weyrich Fig. 15).",
    )
    _common(a, model=True)
    a = sub.add_parser(
        "cca",
        help="canonical correlation of region BRDF means with skin type, gender, age (Fig. 16)",
        description="CCA of the 20 region means of (rho_s, m) against skin type, gender and age, "
        "with principal and direct correlations, Bartlett and permutation tests "
        "(Weyrich Fig. 16).",
    )
    _common(a, model=True)
    _permutations(a)
    a = sub.add_parser(
        "scatter",
        help="sigma_a against sigma_s' per subject and channel (Fig. 14)",
        description="Absorption against reduced scattering of every subject per channel, coloured by "
        "skin type, marker by gender, size by age (Weyrich Fig. 14).",
    )
    _common(a)
    a.add_argument(
        "--site",
        type=non_empty,
        default=None,
        metavar="SITE",
        help="cheek, forehead or neck: coefficients fitted at that site (default: subject-level, "
        "from the albedo and sigma_trAvg as in the paper)",
    )
    a = sub.add_parser(
        "translucency",
        help="mean and spread of sigma_tr per site, sigma_trAvg, l_d extremes (Table 1)",
        description="Weyrich Table 1 (mean and variance of sigma_tr per site and channel) with the "
        "published values side by side, sigma_trAvg and the least/most translucent "
        "subjects.",
    )
    _common(a)
    a = sub.add_parser(
        "conditions",
        help="BRDF differences of the person measured under seven conditions (§7)",
        description="Per-region differences of the specular parameters of one person between external "
        "conditions (normal, cold, hot, sweaty, makeup, lotion, powder), Weyrich §7, and the distance between "
        "every two conditions: the root mean square over the face's texels of their region means' differences, in "
        "one within-region spread per parameter pooled over the person's regions and conditions (a metric). "
        "Regions without texels under some condition are left out and named.",
    )
    _common(a, model=True)
    a = sub.add_parser(
        "models",
        help="Blinn-Phong against Torrance-Sparrow fit error per region, flags, exponents (§5.3, Fig. 7)",
        description="Per face region: median ratio of the Blinn-Phong to the Torrance-Sparrow fit error E(p) "
        "(eq. 14, on the same samples) over the subjects measured under normal conditions, the flagged share "
        "of each model and the Blinn-Phong exponents (Weyrich §5.3, Fig. 7).",
    )
    _common(a)
    a = sub.add_parser(
        "posterior",
        help="Bayesian posterior of sigma_s', sigma_a, sigma_tr of one sensor profile",
        description="emcee posterior of (sigma_s', sigma_a) per channel of one contact-sensor profile, "
        "with sigma_tr and l_d (Weyrich §5.4 with uncertainty). --population instead gives "
        "the posterior of the mean sigma_tr per skin type.",
    )
    _common(a)
    a.add_argument(
        "--subject",
        type=non_empty,
        default=None,
        metavar="ID",
        help="subject id (default: the first subject measured under normal conditions)",
    )
    a.add_argument(
        "--site", type=non_empty, default=None, metavar="SITE", help="cheek, forehead or neck (default cheek)"
    )
    a.add_argument(
        "--noise",
        choices=("model", "stored"),
        default="model",
        help="likelihood noise: the sensor noise model (default) or the stored profile std",
    )
    a.add_argument("--seed", type=ascii_int, default=0, help="sampler seed (default 0)")
    a.add_argument(
        "--population",
        action="store_true",
        help="posterior of the mean sigma_tr per skin type instead (writes posterior_population.*)",
    )
    a = sub.add_parser(
        "all",
        help="every analysis but the posterior",
        description="Run pca, cca, scatter, translucency, conditions and models. An analysis the store cannot "
        "support is skipped with the reason: cca with no more subjects than variables, scatter and translucency "
        "without sensor data, conditions without a person measured under several conditions, models without "
        "fitted maps. Every file is written, or none.",
    )
    _common(a, model=True)
    _permutations(a)
    a.set_defaults(site=None)
    for action in ACTIONS:
        sub.choices[action].set_defaults(func=_cmd_analyze)
    return p

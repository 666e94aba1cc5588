"""``helicalib fit OBSERVATIONS --field FIELD.yaml --heliostat ID [--loo] [--split KIND] [--json]``: fit the
error model to stored observations and report in-sample, leave-one-out and benchmark-split (out-of-sample)
errors."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass

import numpy as np

from helicalib.calibration.splits import DEFAULT_TEST_SHARE, SPLITS
from helicalib.commands._args import float_in, nonnegative_int, positive_float


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fit", help="fit a heliostat's error model to stored observations",
                       description="MAP fit of the named error model (Gaussian priors; calibration.fit's "
                                   "fit_error_model, normal residuals) to an observations CSV; "
                                   "reports the mirror-normal error (mrad) and the beam error on the target (m), "
                                   "nominal, in-sample and, with --loo, leave-one-out.")
    p.add_argument("observations", help="observations CSV (helicalib import-paint or a campaign export)")
    p.add_argument("--field", required=True, help="field config YAML")
    p.add_argument("--heliostat", required=True, help="heliostat id")
    p.add_argument("--loo", action="store_true", help="also fit leaving each observation out in turn")
    p.add_argument("--prior", action="append", default=[], metavar="NAME=SIGMA",
                   help="override a parameter's prior sigma (in its unit; 0 fixes it at nominal)")
    p.add_argument("--sigma-meas-mrad", type=positive_float, default=1.0, help="normal-error scatter of one observation")
    p.add_argument("--split", action="append", default=[], choices=[*SPLITS, "all"],
                   help="fit on the train part of a PAINT benchmark split by sun position and report the error on "
                        "the test part (out of sample), beside leave-one-out; repeat it or give 'all'")
    p.add_argument("--test-share", type=float_in(0.0, 1.0, open_lo=True, open_hi=True), default=DEFAULT_TEST_SHARE,
                   help=f"share of the observations in a split's test part (default {DEFAULT_TEST_SHARE})")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the balanced split's k-means and draws (default 0)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def _mean(a) -> float | None:
    a = np.asarray(a, dtype=float)
    return float(np.mean(a)) if a.size else None


def _rms(a) -> float | None:
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a**2))) if a.size else None


@dataclass(frozen=True)
class FitReportOptions:
    """How ``helicalib fit`` fits and what it reports: ``priors`` (parameter name → prior sigma in its
    unit; 0 fixes it at nominal), ``sigma_meas_mrad`` (the scatter of one observation), ``loo``
    (leave-one-out too), ``splits`` (benchmark splits, :data:`~helicalib.calibration.splits.SPLITS`),
    their ``test_share`` and ``seed``."""

    priors: dict
    sigma_meas_mrad: float = 1.0
    loo: bool = False
    splits: tuple[str, ...] = ()
    test_share: float = DEFAULT_TEST_SHARE
    seed: int = 0


def split_report(model, strokes, sun, spot, targets, split, options: FitReportOptions, record_ids) -> dict:
    """Fit on ``split.train``, predict ``split.test``: the out-of-sample errors of one benchmark split."""
    from helicalib.realdata.fitting import beam_error_m, fit, normal_error_mrad

    tr, te = split.train, split.test
    res = fit(model, strokes[tr], sun[tr], spot[tr], prior_sigma=options.priors,
              sigma_meas_mrad=options.sigma_meas_mrad)
    test_normal = normal_error_mrad(res.model, strokes[te], sun[te], spot[te])
    test_beam = beam_error_m(res.model, strokes[te], sun[te], spot[te], [targets[i] for i in te])
    train_normal = normal_error_mrad(res.model, strokes[tr], sun[tr], spot[tr])
    return {"split": split.kind, "train": len(tr), "test": len(te),
            "test_record_ids": [record_ids[i] for i in te],
            "train_normal_mrad_rms": _rms(train_normal),
            "test_normal_mrad_rms": _rms(test_normal), "test_normal_mrad_mean": _mean(test_normal),
            "test_normal_mrad": test_normal.tolist(),
            "test_beam_m_rms": _rms(test_beam), "test_beam_m_mean": _mean(test_beam), "converged": res.success}


def fit_report(cfg, rows, heliostat_id: str, options: FitReportOptions) -> dict:
    """The fit of ``heliostat_id``'s observations ``rows``: nominal and in-sample errors, parameters and
    their identifiability, and (as ``options`` asks) leave-one-out and the benchmark splits."""
    from helicalib.calibration.observations import observations_arrays
    from helicalib.geometry import error_model as em
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.realdata.fitting import beam_error_m, fit, identifiability, leave_one_out, normal_error_mrad

    priors, sigma_meas_mrad, splits = options.priors, options.sigma_meas_mrad, options.splits
    a = observations_arrays(rows)
    targets = [cfg.target(r.target_id) for r in rows]
    model = HeliostatModel.from_config(cfg, [heliostat_id])
    args = (a["strokes_mm"], a["sun_enu"], a["spot_enu"])
    nominal = normal_error_mrad(model, *args)
    res = fit(model, *args, prior_sigma=priors, sigma_meas_mrad=sigma_meas_mrad)
    prior_sig = em.prior_sigma(priors)
    in_sample = normal_error_mrad(res.model, *args)
    ins_beam = beam_error_m(res.model, *args, targets)
    rep = {
        "heliostat": heliostat_id,
        "records": len(rows),
        "record_ids": [r.record_id for r in rows],
        "fitter": "calibration.fit.fit_error_model (residual_kind=normal, loss=linear)",
        "priors": {n: float(s) for n, s in zip(em.NAMES, prior_sig)},
        "sigma_meas_mrad": sigma_meas_mrad,
        "nominal_normal_mrad_mean": _mean(nominal),
        "nominal_normal_mrad": nominal.tolist(),
        "nominal_beam_m_mean": _mean(beam_error_m(model, *args, targets)),
        "in_sample_normal_mrad_mean": _mean(in_sample),
        "in_sample_normal_mrad": in_sample.tolist(),
        "in_sample_beam_m_mean": _mean(ins_beam),
        "parameters": {p.name: {"value": float(v), "sigma": float(s), "unit": p.unit, "prior_sigma": float(ps)}
                       for p, v, s, ps in zip(em.PARAMETERS, res.params, res.sigma, prior_sig)},
        "identifiability": identifiability(res, priors),
        "converged": res.success,
    }
    if options.loo:
        lo = leave_one_out(model, *args, targets, prior_sigma=priors, sigma_meas_mrad=sigma_meas_mrad)
        rep.update({"loo_normal_mrad_mean": _mean(lo["normal_mrad"]), "loo_normal_mrad": lo["normal_mrad"].tolist(),
                    "loo_normal_mrad_rms": _rms(lo["normal_mrad"]),
                    "loo_beam_m_mean": _mean(lo["beam_m"]), "loo_beam_m": lo["beam_m"].tolist()})
    if splits:
        from helicalib.calibration.splits import make_split

        strokes, sun, spot = (np.asarray(x, dtype=float) for x in args)
        rep["test_share"], rep["seed"] = options.test_share, options.seed
        rep["splits"] = {kind: split_report(model, strokes, sun, spot, targets,
                                            make_split(kind, sun, cfg.site.latitude_deg, options.test_share,
                                                       options.seed),
                                            options, rep["record_ids"]) for kind in splits}
    return rep


def run(args) -> int:
    from helicalib.calibration.observations import read_observations
    from helicalib.config import load_field_config
    from helicalib.errors import ConfigError, MeasurementError
    from helicalib.realdata.fitting import REALDATA_PRIOR_SIGMA

    cfg = load_field_config(args.field)
    cfg.heliostat(args.heliostat)
    rows = read_observations(args.observations, args.heliostat)
    targets = {t.id for t in cfg.targets}
    for r in rows:
        if r.target_id not in targets:
            raise MeasurementError(f"{args.observations}: record {r.record_id[:40]!r}: target_id: no target "
                                   f"{r.target_id[:40]!r} in {args.field}")
    if len(rows) < 2:
        raise MeasurementError(f"{args.observations}: {len(rows)} observation(s) of {args.heliostat}; need at least 2")
    priors = dict(REALDATA_PRIOR_SIGMA)
    for item in args.prior:
        name, _, value = item.partition("=")
        try:
            sigma = float(value)
        except ValueError:
            raise ConfigError(f"--prior {item}: expected NAME=SIGMA") from None
        if not (math.isfinite(sigma) and sigma >= 0):
            raise ConfigError(f"--prior {item}: SIGMA must be a finite number >= 0 (0 fixes the parameter)")
        priors[name.strip()] = sigma
    from helicalib.geometry import error_model as em
    for name in priors:
        if name not in em.NAMES:
            raise ConfigError(f"--prior {name}: unknown parameter; known: {', '.join(em.NAMES)}")
    splits = tuple(SPLITS if "all" in args.split else dict.fromkeys(args.split))
    loo = args.loo or bool(splits)  # a split's out-of-sample error is reported beside leave-one-out
    if loo and len(rows) < 3:
        raise MeasurementError(f"{args.observations}: {len(rows)} observations of {args.heliostat}; "
                               "leave-one-out and the splits need at least 3")
    rep = fit_report(cfg, rows, args.heliostat, FitReportOptions(priors, args.sigma_meas_mrad, loo, splits,
                                                           args.test_share, args.seed))
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    print(f"{args.heliostat}: {rep['records']} observations")
    print(f"  normal error, nominal    {rep['nominal_normal_mrad_mean']:.2f} mrad mean "
          f"(beam {rep['nominal_beam_m_mean']:.2f} m)")
    print(f"  normal error, in-sample  {rep['in_sample_normal_mrad_mean']:.2f} mrad mean "
          f"(beam {rep['in_sample_beam_m_mean']:.3f} m)")
    if loo:
        print(f"  normal error, leave-one-out {rep['loo_normal_mrad_mean']:.2f} mrad mean, "
              f"{rep['loo_normal_mrad_rms']:.2f} RMS (beam {rep['loo_beam_m_mean']:.3f} m)")
    for kind, sp in rep.get("splits", {}).items():
        print(f"  normal error, split {kind:13s} {sp['test_normal_mrad_rms']:.2f} mrad RMS out of sample "
              f"({sp['test']} test / {sp['train']} train; train {sp['train_normal_mrad_rms']:.2f} RMS; "
              f"beam {sp['test_beam_m_rms']:.3f} m RMS)")
    print("  parameters (value ± posterior sigma, prior sigma; post/prior near 1 = not identified by the data):")
    ident = {d["name"]: d for d in rep["identifiability"]}
    for name, p in rep["parameters"].items():
        d = ident[name]
        extra = f"post/prior {d['posterior_over_prior']:.2f}" if d.get("free") else "fixed"
        print(f"    {name:28s} {p['value']:+10.4f} ± {p['sigma']:.4f} {p['unit']:4s} (prior {p['prior_sigma']:g}; {extra})")
    return 0

"""``helicalib fit OBSERVATIONS --field FIELD.yaml --heliostat ID [--loo] [--json]``: fit the error model
to stored observations and report in-sample and leave-one-out errors."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

from helicalib.commands._args import positive_float


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
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def _mean(a) -> float | None:
    a = np.asarray(a, dtype=float)
    return float(np.mean(a)) if a.size else None


def fit_report(cfg, rows, heliostat_id: str, loo: bool, priors: dict, sigma_meas_mrad: float = 1.0) -> dict:
    from helicalib.calibration.observations import observations_arrays
    from helicalib.geometry import errors as em
    from helicalib.geometry.heliostat import HeliostatModel
    from helicalib.realdata.fitting import beam_error_m, fit, identifiability, leave_one_out, normal_error_mrad

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
    if loo:
        lo = leave_one_out(model, *args, targets, prior_sigma=priors, sigma_meas_mrad=sigma_meas_mrad)
        rep.update({"loo_normal_mrad_mean": _mean(lo["normal_mrad"]), "loo_normal_mrad": lo["normal_mrad"].tolist(),
                    "loo_beam_m_mean": _mean(lo["beam_m"]), "loo_beam_m": lo["beam_m"].tolist()})
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
    from helicalib.geometry import errors as em
    for name in priors:
        if name not in em.NAMES:
            raise ConfigError(f"--prior {name}: unknown parameter; known: {', '.join(em.NAMES)}")
    if args.loo and len(rows) < 3:
        raise MeasurementError("leave-one-out needs at least 3 observations")
    rep = fit_report(cfg, rows, args.heliostat, args.loo, priors, args.sigma_meas_mrad)
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    print(f"{args.heliostat}: {rep['records']} observations")
    print(f"  normal error, nominal    {rep['nominal_normal_mrad_mean']:.2f} mrad mean "
          f"(beam {rep['nominal_beam_m_mean']:.2f} m)")
    print(f"  normal error, in-sample  {rep['in_sample_normal_mrad_mean']:.2f} mrad mean "
          f"(beam {rep['in_sample_beam_m_mean']:.3f} m)")
    if args.loo:
        print(f"  normal error, leave-one-out {rep['loo_normal_mrad_mean']:.2f} mrad mean "
              f"(beam {rep['loo_beam_m_mean']:.3f} m)")
    print("  parameters (value ± posterior sigma, prior sigma; post/prior near 1 = not identified by the data):")
    ident = {d["name"]: d for d in rep["identifiability"]}
    for name, p in rep["parameters"].items():
        d = ident[name]
        extra = f"post/prior {d['posterior_over_prior']:.2f}" if d.get("free") else "fixed"
        print(f"    {name:28s} {p['value']:+10.4f} ± {p['sigma']:.4f} {p['unit']:4s} (prior {p['prior_sigma']:g}; {extra})")
    return 0

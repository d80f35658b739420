"""The text tables ``pdcov detector fit`` and ``validate`` print: per size bin P_D, 1 -
precision and false boxes per Mpx with their intervals; the looks, blur and confidence
sections; a validation's observed and predicted counts with p-values."""

from __future__ import annotations

from pdcov.core.detector import DetectorModel
from pdcov.detection.looks_fit import LooksFit, found_within
from pdcov.detection.validation import ValidationReport


def format_model_table(model: DetectorModel) -> str:
    """Per-bin table: size range, P_D with its interval and counts, the paper's 1 -
    precision likewise, and the false boxes per frame per Mpx (what the grid uses)."""
    ci_d = model.extra.get("p_detect_ci95")
    ci_fa = model.extra.get("p_false_alarm_ci95")
    ci_rate = model.extra.get("fa_rate_per_mpx_ci95")
    rate = model.fa_rate_per_mpx
    c = model.counts
    rows = [f"{'size px':>15} {'N_true':>7} {'N_det':>7} {'P_D':>6} {'95% CI':>15} "
            f"{'N_total':>7} {'1-prec':>6} {'95% CI':>15} {'FA/Mpx':>8} {'95% CI':>19}"]
    for i in range(model.n_bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        rows.append(
            f"{lo:7.1f}-{hi:<7.1f} "
            f"{c.n_true[i] if c else '':>7} {c.n_detected[i] if c else '':>7} "
            f"{model.p_detect[i]:6.3f} {_ci(ci_d, i):>15} "
            f"{c.n_detections[i] if c else '':>7} {model.p_false_alarm[i]:6.3f} "
            f"{_ci(ci_fa, i):>15} {f'{rate[i]:8.4g}' if rate else '':>8} "
            f"{_ci_rate(ci_rate, i):>19}")
    return "\n".join(rows)


def _ci_rate(ci: list[list[float]] | None, i: int) -> str:
    return f"[{ci[i][0]:.3g}, {ci[i][1]:.3g}]" if ci else ""


LOOKS_EXAMPLE = 20  # looks for the "found within n looks" column of the looks table


def format_looks_table(model: DetectorModel, fit: LooksFit) -> str:
    """Per bin: people and looks, the beta-binomial mean P_D and correlation with their
    intervals, the p-value of independence, and the share found within 20 looks by the
    independent and by the fitted model; then the bins without an estimate."""
    n = LOOKS_EXAMPLE
    rows = [f"{'size px':>15} {'people':>6} {'looks':>7} {'mean P_D':>8} {'95% CI':>15} "
            f"{'rho':>6} {'95% CI':>15} {'p indep':>8} {f'{n} looks: indep':>16} "
            f"{'fitted':>6}"]
    missing = []
    for i, b in enumerate(fit.bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        head = f"{lo:7.1f}-{hi:<7.1f} {b.n_people:6d} {b.n_looks:7d} "
        if not b.estimated:
            rows.append(head + f"{'-':>8} {'':>15} {'-':>6}   no estimate: {b.reason}")
            missing.append(i)
            continue
        indep, fitted = (float(found_within(n, b.mean_pd, r)) for r in (0.0, b.correlation))
        rows.append(head + f"{b.mean_pd:8.3f} {_ci([list(b.mean_pd_ci95)], 0):>15} "
                    f"{b.correlation:6.3f} {_ci([list(b.correlation_ci95)], 0):>15} "
                    f"{b.p_value_independent:8.2g} {indep:16.5f} {fitted:6.3f}")
    rows.append("mean P_D and rho (intra-person correlation) of a beta-binomial per-person "
                "detectability, profile-likelihood 95 % intervals; p indep: likelihood-ratio "
                "test of independent looks (rho = 0), chi-bar-square")
    if missing:
        rows.append(f"no estimate in {len(missing)} of {len(fit.bins)} bins: the engine takes "
                    f"their looks as independent (rho = 0), which may overstate coverage")
    return "\n".join(rows)


def format_blur_table(model: DetectorModel) -> str:
    """P_D by blur bin (rows) and size bin (columns), with each cell's object count."""
    blur = model.blur
    assert blur is not None
    n_true = blur.extra.get("n_true")
    head = " ".join(f"{model.bin_edges_px[i]:>6.1f}+" for i in range(model.n_bins))
    rows = ["P_D by blur (rows) and size (columns, from px):", f"{'blur px':>13} {head}"]
    for j, row in enumerate(blur.p_detect):
        lo, hi = blur.edges_px[j], blur.edges_px[j + 1]
        rows.append(f"{lo:6.2f}-{hi:<6.2f} " + " ".join(f"{p:7.3f}" for p in row)
                    + (f"   (objects {sum(n_true[j])})" if n_true else ""))
    return "\n".join(rows)


def format_confidence_table(model: DetectorModel) -> str:
    """The evidence of a box's confidence, log(f_TP / f_FP), by size bin (rows) and
    confidence bin (columns), with each size bin's true and false boxes."""
    conf = model.confidence
    assert conf is not None
    n_tp = conf.extra.get("n_true_positives")
    n_fp = conf.extra.get("n_false_positives")
    lr = conf.log_lr_table()
    head = " ".join(f"{e:>6.3g}+" for e in conf.edges[:-1])
    rows = [f"confidence evidence log(f_TP / f_FP) by size (rows) and confidence (columns, "
            f"from), {conf.extra.get('smoothing', 'as given')} smoothing:",
            f"{'size px':>15} {'TP':>6} {'FP':>6} {head}"]
    for i in range(model.n_bins):
        lo, hi = model.bin_edges_px[i], model.bin_edges_px[i + 1]
        counts = (f"{sum(n_tp[i]):6d} {sum(n_fp[i]):6d}" if n_tp and n_fp
                  else f"{'':6} {'':6}")
        rows.append(f"{lo:7.1f}-{hi:<7.1f} {counts} " + " ".join(f"{v:7.2f}" for v in lr[i]))
    return "\n".join(rows)


def _ci(ci: list[list[float]] | None, i: int) -> str:
    return f"[{ci[i][0]:.3f}, {ci[i][1]:.3f}]" if ci else ""


def format_validation_table(report: ValidationReport) -> str:
    """Per-bin observed and predicted counts with p-values: detections among objects (P_D),
    true among detections (precision, the paper's 1 - P_FA), and false boxes with their rate
    per frame per Mpx (the grid's P_FA); then the number of bins failing."""
    rows = [f"{'size px':>15} {'N_true':>7} {'det':>6} {'pred':>8} {'p':>8}   "
            f"{'N_total':>7} {'TP':>6} {'pred':>8} {'p':>8}   "
            f"{'FP':>6} {'pred':>8} {'FA/Mpx':>8} {'95% CI':>19} {'p':>8}"]

    def p(v: float | None) -> str:
        return "-" if v is None else f"{v:.3g}" + ("*" if v < report.alpha else "")

    for i, (d, q) in enumerate(zip(report.detect, report.precision, strict=True)):
        lo, hi = report.bin_edges_px[i], report.bin_edges_px[i + 1]
        row = (f"{lo:7.1f}-{hi:<7.1f} {d.n:7d} {d.observed:6d} {d.expected:8.1f} "
               f"{p(d.p_value):>8}   {q.n:7d} {q.observed:6d} {q.expected:8.1f} "
               f"{p(q.p_value):>8}")
        if report.fa_rate:
            r = report.fa_rate[i]
            pred = "-" if r.expected is None else f"{r.expected:8.1f}"
            row += (f"   {r.observed:6d} {pred:>8} {r.rate_per_mpx:8.4g} "
                    f"{_ci_rate([list(r.rate_ci95)], 0):>19} {p(r.p_value):>8}")
        rows.append(row)
    fd, nd = report.n_failed("detect")
    fp, np_ = report.n_failed("precision")
    fr, nr = report.n_failed("fa_rate")
    test = {"binomial": "exact binomial", "chi2": "chi-square", "fisher": "Fisher exact"}[
        report.test]
    rate = (f", false boxes per Mpx in {fr} of {nr} bins ("
            f"{'two-sample Poisson' if report.test == 'fisher' else 'exact Poisson'})"
            if nr else "")
    rows.append(f"{test} tests, * p < {report.alpha:g}: P_D fails in {fd} of {nd} bins, "
                f"precision in {fp} of {np_} bins{rate}")
    if not report.fa_rate:
        rows.append("false boxes per Mpx not measured: the images' sizes are unknown "
                    "(--sizes FILE or --images DIR)")
    elif not nr:
        rows.append("false boxes per Mpx not tested: the model's rate (fa_rate_per_mpx, "
                    "version 4) is compared on the model's own bins only"
                    + (", with the fit's counts for --test fisher"
                       if report.test == "fisher" else ""))
    return "\n".join(rows)

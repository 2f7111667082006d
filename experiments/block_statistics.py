"""Do the radar block's statistics pass their own tests? (issue 12, acceptance experiment)

Blunder-free simulated AIDJEX blocks — the scenario of ``seaice simulate aidjex`` (10 strips, 600 features, two
coverages 16 days apart, three drifting stations as control) with different seeds — adjusted by
:func:`~seaice_jax.adjust.block.simultaneous_block` with the default options (``seaice block``), for each
navigation scope (flight, strip). If the stochastic model is right:

* σ̂0 ≈ 1 (mean within 1 ± 0.03), and the global test (χ², α = 0.05) rejects 2-10 % of the blocks;
* the w-test (α = 0.001) flags about 0.1 % of the image observations in each coordinate (target ≤ 2α);
* the predicted σ of the adjusted positions (stations, all points) and of the drift vectors matches the
  empirical error: √mean(e²/σ²) per map coordinate within 10 % of 1 — judged conditioned on the stations'
  satellite fixes (:func:`normalized`): they shift each coverage as a whole, and the plain ratios of 40 blocks follow
  their luck (seeds 1000-1039: the fixes alone give 0.87 for the drift vectors, whose error is the difference of
  two coverages' fixes);
* a planted 5 mm image blunder and a 1 km control-point blunder are flagged and named.

It also measures the navigation noise that reaches the geometry (records with only their white noise): the RMS
error of the interpolated velocity between records and the along-track displacement of far-range points, with
today's filter (:func:`~seaice_jax.sensors.strips.strip_navigation`) and with the moving polynomial's positions
and derivatives interpolated by a Hermite cubic (the filter before issue 12).

Run: ``python experiments/block_statistics.py`` (30 blocks per scope, about 10 minutes on 2 cores) or
``--realizations 3`` for a quick look; ``--image-sigma``, ``--sweep-delay-prior``, ``--range-scale-prior``,
``--filter-window`` try other options. Writes ``experiments/results/block_statistics.md``.
"""

import argparse
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from seaice_jax.adjust.block import BlockOptions, simultaneous_block
from seaice_jax.adjust.quality import critical_value, global_test
from seaice_jax.errors import SeaiceError
from seaice_jax.geometry.earth import MEAN_RADIUS
from seaice_jax.geometry.range_doppler import look_sign
from seaice_jax.sensors.navigation import NavigationSpline, moving_average
from seaice_jax.sensors.strips import image_to_ground, strip_ground_points, strip_navigation
from seaice_jax.simulate.aircraft import ErrorModel, FlightPlan, aidjex_scenario, simulate_flight

RESULTS = Path(__file__).parent / "results" / "block_statistics.md"
SCOPES = ("flight", "strip")
W_ALPHA = 0.001
GLOBAL_ALPHA = 0.05
MIN_REGRESSION_BLOCKS = 10
"""Blocks below which the conditioned ratios are not formed (β is regressed over the blocks)."""


def scenario(seed):
    """The block ``seaice simulate aidjex --seed seed`` writes (default strips and features)."""
    return aidjex_scenario(seed, plan=FlightPlan(strips=10), features=600)


def normalized(blocks, resamples=2000, seed=0):
    """√mean(e²/σ²) per coordinate ``(2,)`` over all rows with finite values of the ``blocks`` (a list of
    ``(errors (n, 2), covariances (n, 2, 2), control variate (2,))``) and its 95 % interval ``(2, 2)`` by
    resampling whole blocks (the errors within a block share its navigation and radar errors and the stations'
    fixes: the blocks, not the points, are independent); then the same conditioned on the stations' fixes, and
    its interval (NaN without a control variate).

    The stations' satellite fixes (100 m, three per coverage) shift a whole coverage: they dominate a block's
    errors, so each block gives about one sample per coordinate of them, and 40 blocks place the ratio only to
    about ±0.15 (the drift vectors least well: their error holds the difference of two coverages' fixes). The
    control variate ``c`` of a block (:func:`_control_variate`) is the normalized square of that fix error, whose
    expectation is exactly 1 by the simulation's construction: mean(e²/σ²) − β (mean(c) − 1), β regressed over
    the blocks, has the same expectation and a 2-3 times narrower interval (NaN below
    :data:`MIN_REGRESSION_BLOCKS` blocks; a resample whose blocks are all one gives no β and no interval value)."""
    sums, counts, variates = [], [], []
    for errors, covariances, variate in blocks:
        errors, covariances = np.asarray(errors).reshape(-1, 2), np.asarray(covariances).reshape(-1, 2, 2)
        sigma2 = np.diagonal(covariances, axis1=1, axis2=2)
        ok = np.isfinite(errors).all(axis=1) & np.isfinite(sigma2).all(axis=1)
        sums.append(np.sum(errors[ok] ** 2 / sigma2[ok], axis=0))
        counts.append(ok.sum())
        variates.append(variate)
    sums, counts, variates = np.array(sums), np.array(counts, float), np.array(variates, float)

    def estimates(pick):
        s, n, c = sums[pick], counts[pick][..., None], variates[pick]
        raw = s.sum(axis=-2) / n.sum(axis=-2)
        # β: weighted regression of the blocks' mean(e²/σ²) on their control variate (weights: rows per block)
        mean_c = (n * c).sum(axis=-2) / n.sum(axis=-2)
        spread = (n * (c - mean_c[..., None, :]) ** 2).sum(axis=-2)
        beta = (n * (c - mean_c[..., None, :]) * (s / n - raw[..., None, :])).sum(axis=-2) / spread
        return np.sqrt(raw), np.sqrt(np.maximum(raw - beta * (mean_c - 1.0), 0.0))

    pick = np.random.default_rng(seed).integers(0, len(blocks), (resamples, len(blocks)))
    with np.errstate(invalid="ignore", divide="ignore"):
        raw, conditioned = estimates(np.arange(len(blocks)))
        raw_resampled, conditioned_resampled = estimates(pick)
    if len(blocks) < MIN_REGRESSION_BLOCKS:
        conditioned, conditioned_resampled = np.full(2, np.nan), np.full((resamples, 2), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: no control variate
        conditioned_interval = np.nanquantile(conditioned_resampled, [0.025, 0.975], axis=0).T
    return raw, np.quantile(raw_resampled, [0.025, 0.975], axis=0).T, conditioned, conditioned_interval


def _control_variate(sim):
    """Per coverage ``(coverages, 2)`` the stations' mean fix error (known position − truth, m) over its σ: a
    standard normal per coordinate by the simulation's construction (NaN without control points)."""
    out = []
    for coverage, truth in zip(sim.coverages, sim.truth, strict=True):
        stations = np.array(sorted(coverage.control), int)
        if not stations.size:
            out.append(np.full(2, np.nan))
            continue
        fixes = np.array([coverage.control[i][:2] for i in stations])
        sigma = np.array([coverage.control[i][2] for i in stations])
        out.append((fixes - truth.positions[stations]).mean(axis=0) / (np.sqrt(np.sum(sigma**2)) / stations.size))
    return np.array(out)


def block_statistics(seed, options):
    """One blunder-free block: σ̂0, dof, global-test acceptance, w-test alarms and normalized errors."""
    sim = scenario(seed)
    n = sim.kinds.size
    result = simultaneous_block(sim.coverages, sim.plane, n, options)
    _, _, accepted = global_test(result.sigma0**2, result.degrees_of_freedom, GLOBAL_ALPHA)
    alarms = np.abs(result.w) > float(critical_value(W_ALPHA))
    stations = np.nonzero(sim.kinds == "station")[0]
    errors = {"stations": [], "points": [], "drift": []}
    covariances = {"stations": [], "points": [], "drift": []}
    fix = _control_variate(sim)
    variates = {"stations": np.mean(fix**2, axis=0), "points": np.mean(fix**2, axis=0),
                "drift": np.mean((fix[1:] - fix[:-1]) ** 2 / 2.0, axis=0)}
    for c, truth in enumerate(sim.truth):
        e = result.positions[c] - truth.positions
        errors["points"].append(e)
        covariances["points"].append(result.covariances[c])
        errors["stations"].append(e[stations])
        covariances["stations"].append(result.covariances[c][stations])
    for k, (drift, covariance) in enumerate(zip(result.drift, result.drift_covariance, strict=True)):
        errors["drift"].append(drift - (sim.truth[k + 1].positions - sim.truth[k].positions))
        covariances["drift"].append(covariance)
    return dict(sigma0=result.sigma0, dof=result.degrees_of_freedom, accepted=bool(accepted),
                alarms=alarms.sum(axis=0), observations=alarms.shape[0],
                errors={k: np.concatenate(v) for k, v in errors.items()},
                covariances={k: np.concatenate(v) for k, v in covariances.items()}, variates=variates)


def _named(result, point, coverage, strip=None, component=None, group="image"):
    """The flagged observation naming this point (and strip, component) of ``group``, and its rank among the
    flagged (0 = worst); ``(None, None)`` if none."""
    for rank, b in enumerate(result.blunders):
        if (getattr(b, "group", "image") == group and b.point == point and b.coverage == coverage
                and (strip is None or b.strip == strip) and (component is None or b.component == component)):
            return rank, b
    return None, None


def _describe(rank, blunder, unit):
    if blunder is None:
        return "not flagged"
    text = f"rank {rank}, w = {blunder.w:+.1f}, estimated {blunder.estimated_error:+.2f} {unit}"
    if not getattr(blunder, "separable", True):
        text += f", not separable from {blunder.confounded_with}"
    return text


def planted_blunders(seed, options, rng, component):
    """A 5 mm error on one image coordinate (``"x"`` or ``"y"``) of a tie point, and 1 km on a control point's x:
    flagged and named?"""
    sim = scenario(seed)
    n = sim.kinds.size
    coverage = sim.coverages[0]
    m = coverage.measurements
    # a tie point whose every measurement has a ground solution (near-range ones may have none, and are dropped)
    solved = np.bincount(m.point, weights=np.isfinite(strip_ground_points(coverage.strips, m)).all(axis=1),
                         minlength=n)
    ties = np.nonzero((np.bincount(m.point, minlength=n) >= 2) & (solved == np.bincount(m.point, minlength=n))
                      & (sim.kinds == "ice"))[0]
    row = rng.choice(np.nonzero(np.isin(m.point, ties))[0])
    shifted = replace(m, **{component: getattr(m, component) + np.where(np.arange(m.x.size) == row, 5.0, 0.0)})
    out = dict(image=f"point {m.point[row]} strip {m.strip[row]} {component}")
    try:
        image = simultaneous_block((replace(coverage, measurements=shifted), sim.coverages[1]), sim.plane, n,
                                   options)
        out["image"] += ": " + _describe(*_named(image, int(m.point[row]), 0, int(m.strip[row]), component), "mm")
    except SeaiceError as error:
        out["image"] += f": solve failed ({str(error)[:60]}...)"
    station = 0
    x, y, sigma = coverage.control[station]
    control = dict(coverage.control)
    control[station] = (x + 1000.0, y, sigma)
    bad = simultaneous_block((replace(coverage, control=control), sim.coverages[1]), sim.plane, n, options)
    tested = any(getattr(b, "group", "image") == "control" for b in bad.blunders)
    out["control"] = _describe(*_named(bad, station, 0, None, "x", "control"), "m") + (
        "" if tested else " (no control point flagged: not w-tested by this engine?)")
    out["worst"] = "; ".join((getattr(b, "description", "") or f"{b.point}/{b.component}") + f" w={b.w:+.1f}"
                             for b in bad.blunders[:3]) or "none"
    return out


def navigation_noise(seeds=3, filter_window=180.0):
    """RMS velocity error (m/s, per ECEF coordinate, between records) and along-track displacement (m) of
    far-range points, records with only their white noise, for today's filter and the moving polynomial +
    Hermite of before."""
    errors = ErrorModel().only("record_noise", "velocity_noise")
    plan = FlightPlan()

    def before(strip):
        positions, velocities = moving_average(strip.record_times, strip.record_positions, filter_window, 2)
        return NavigationSpline(strip.record_times, positions, velocities)

    methods = {"moving polynomial + Hermite (before)": before,
               "strip_navigation (positions and velocities, one spline)":
                   lambda s: strip_navigation(s, filter_window)}
    out = {}
    for label, navigate in methods.items():
        velocity, along = [], []
        for seed in range(seeds):
            for strip, truth in zip(*simulate_flight(plan, errors, np.random.default_rng(seed), 3600.0), strict=True):
                navigation = navigate(strip)
                t = np.linspace(strip.start_time, strip.end_time, 1801)
                velocity.append(np.asarray(navigation(t)[1]) - np.asarray(truth.trajectory(t)[1]))
                x = np.linspace(strip.mark_x[0], strip.mark_x[-1], 301)
                y = np.full_like(x, plan.far_range / truth.range_scale - truth.sweep_delay)
                args = (jnp.asarray(strip.mark_x), jnp.asarray(strip.mark_times), jnp.asarray(x), jnp.asarray(y),
                        truth.sweep_delay, truth.range_scale, look_sign(strip.look_side), MEAN_RADIUS)
                shift = (np.asarray(image_to_ground(navigation, *args))
                         - np.asarray(image_to_ground(truth.trajectory, *args)))
                heading = np.asarray(truth.trajectory(np.interp(x, strip.mark_x, strip.mark_times))[1])
                heading = heading / np.linalg.norm(heading, axis=1, keepdims=True)
                along.append(np.sum(shift * heading, axis=1))
        velocity = np.concatenate(velocity)
        out[label] = (np.sqrt(np.mean(velocity**2, axis=0)), float(np.sqrt(np.mean(np.concatenate(along) ** 2))))
    return out


def summarize(rows):
    sigma0 = np.array([r["sigma0"] for r in rows])
    alarms = np.sum([r["alarms"] for r in rows], axis=0)
    total = sum(r["observations"] for r in rows)
    ratio, interval, conditioned, conditioned_interval = {}, {}, {}, {}
    for k in rows[0]["errors"]:
        ratio[k], interval[k], conditioned[k], conditioned_interval[k] = normalized(
            [(r["errors"][k], r["covariances"][k], r["variates"][k]) for r in rows])
    return dict(count=len(rows), sigma0=sigma0.mean(), sigma0_sd=sigma0.std(ddof=1) if len(rows) > 1 else np.nan,
                sigma0_min=sigma0.min(), sigma0_max=sigma0.max(), dof=np.mean([r["dof"] for r in rows]),
                rejected=1.0 - np.mean([r["accepted"] for r in rows]), false_alarms=alarms / total, ratio=ratio,
                interval=interval, conditioned=conditioned, conditioned_interval=conditioned_interval,
                fixes={k: np.sqrt(np.mean([r["variates"][k] for r in rows], axis=0)) for k in ratio})


def _judged(summary):
    """The conditioned σ ratios of a scope (the plain ones where there is no control variate)."""
    return np.array([np.where(np.isfinite(summary["conditioned"][k]), summary["conditioned"][k], summary["ratio"][k])
                     for k in summary["ratio"]])


def _check(value, low, high):
    return "yes" if low <= value <= high else "NO"


def report(summaries, blunders, navigation, options, args, elapsed):
    heading = "## " + (args.title or "Options: `BlockOptions` defaults") if args.append else (
        "# Radar block statistics on blunder-free simulated AIDJEX blocks")
    lines = [heading, "",
             f"`python experiments/block_statistics.py {' '.join(args.argv)}` ({elapsed / 60:.0f} min). "
             "Scenario: `seaice simulate aidjex` "
             "(10 strips, 600 features, 2 coverages, 3 stations), seeds "
             f"{args.seed}-{args.seed + args.realizations - 1}; options: `BlockOptions` defaults"
             + (f" except {options}" if options else "") + ".", "",
             "| | " + " | ".join(f"scope {s}" for s in summaries) + " | target |",
             "|---|" + "---|" * len(summaries) + "---|"]

    def row(label, cells, target):
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {target} |")

    row("blocks", [str(s["count"]) for s in summaries.values()], "≥ 30")
    row("mean σ̂0 (sd; range)", [f"{s['sigma0']:.3f} ({s['sigma0_sd']:.3f}; {s['sigma0_min']:.3f}-{s['sigma0_max']:.3f})"
                                 for s in summaries.values()], "1 ± 0.03")
    row("degrees of freedom (mean)", [f"{s['dof']:.0f}" for s in summaries.values()], "")
    row("global test rejected, α = 0.05", [f"{s['rejected']:.2f}" for s in summaries.values()], "0.02-0.10")
    for k, name in enumerate(("x (along track)", "y (slant range)")):
        row(f"w-test alarms {name}, α = 0.001", [f"{s['false_alarms'][k]:.4f}" for s in summaries.values()],
            "≤ 0.002")
    for key, name in (("stations", "stations"), ("points", "all points"), ("drift", "drift vectors")):
        for k, axis in enumerate("xy"):
            row(f"√mean(e²/σ²) {name} {axis} (95 % interval)", [
                f"{s['ratio'][key][k]:.2f} ({s['interval'][key][k, 0]:.2f}-{s['interval'][key][k, 1]:.2f})"
                for s in summaries.values()], "0.9-1.1")
        for k, axis in enumerate("xy"):
            row(f"… conditioned on the stations' fixes, {axis}", [
                f"{s['conditioned'][key][k]:.2f} ({s['conditioned_interval'][key][k, 0]:.2f}-"
                f"{s['conditioned_interval'][key][k, 1]:.2f})" for s in summaries.values()], "0.9-1.1")
        row(f"the stations' fixes alone ({'difference of two coverages' if key == 'drift' else 'per coverage'})"
            ", x, y", [f"{s['fixes'][key][0]:.2f}, {s['fixes'][key][1]:.2f}" for s in summaries.values()],
            "1 (chance)")
    lines += ["", "Targets met: " + "; ".join(
        f"{scope}: σ̂0 {_check(s['sigma0'], 0.97, 1.03)}, global test {_check(s['rejected'], 0.02, 0.10)}, "
        f"w-test {_check(max(s['false_alarms']), 0.0, 2 * W_ALPHA)}, σ "
        f"{_check(float(np.min(_judged(s))), 0.9, 1.1)}"
        f"{'' if np.max(_judged(s)) <= 1.1 else ' (NO: above 1.1)'} (conditioned ratios where formed)"
        for scope, s in summaries.items()), "",
              "Map x is along track and y across (the strips fly east and west); e = adjusted − true position, σ "
              "its predicted (a priori) standard deviation; the 95 % intervals resample whole blocks. The "
              "stations' satellite fixes shift each coverage as a whole and dominate the errors: a block gives "
              "about one sample of them per coordinate, so the plain ratios of 40 blocks are known to about "
              "±0.15 and follow the luck of the seeds' fixes (their row 'alone', expectation 1). Conditioned: "
              "mean(e²/σ²) − β (mean(c) − 1), c that row's per-block square (expectation exactly 1 in the "
              "simulation), β regressed over the blocks: the same expectation, a 2-3 times narrower interval; the "
              "targets are judged on it.", ""]
    if blunders:
        lines += ["## Planted blunders", "",
                  "| scope | seed | 5 mm image blunder: where; rank among flagged (0 = worst), w, estimated error | "
                  "1 km control blunder (station 0, x) | worst three flagged with it |",
                  "|---|---|---|---|---|"]
        for scope, seed, b in blunders:
            lines.append(f"| {scope} | {seed} | {b['image']} | {b['control']} | {b['worst']} |")
        lines.append("")
    lines += ["## Navigation noise reaching the geometry", "",
              "Records with only their white noise (30 m on positions, 0.03 m/s on velocities, north/east), "
              "3 flights of 10 strips; velocity error between records (per Earth-centred coordinate) and "
              "along-track displacement of far-range (55°) points against the truth:", "",
              "| filter (180 s) | velocity error RMS x, y, z (m/s) | far-range along-track RMS (m) |", "|---|---|---|"]
    for label, (velocity, along) in navigation.items():
        lines.append(f"| {label} | {', '.join(f'{v:.3f}' for v in velocity)} | {along:.1f} |")
    lines.append("")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description="Statistics of blunder-free simulated radar blocks (issue 12)")
    parser.add_argument("--realizations", type=int, default=30, help="blocks per navigation scope")
    parser.add_argument("--blunders", type=int, default=3, help="blocks with planted blunders per scope")
    parser.add_argument("--seed", type=int, default=1000, help="first seed")
    parser.add_argument("--scopes", nargs="+", choices=SCOPES, default=list(SCOPES))
    parser.add_argument("--image-sigma", type=float, nargs=2, default=None, help="σx σy mm")
    parser.add_argument("--sweep-delay-prior", type=float, default=None, help="mm")
    parser.add_argument("--range-scale-prior", type=float, default=None, help="relative")
    parser.add_argument("--filter-window", type=float, default=None, help="s")
    parser.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                        help="any other numeric BlockOptions field, e.g. --option turn_prior=300")
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--append", action="store_true", help="add this run's report to --out as a section")
    parser.add_argument("--title", default=None, help="the section's title (with --append)")
    args = parser.parse_args(argv)
    args.argv = sys.argv[1:] if argv is None else list(argv)
    changed: dict[str, Any] = {name: value for name, value in (
        ("image_sigma", None if args.image_sigma is None else tuple(args.image_sigma)),
        ("sweep_delay_prior", args.sweep_delay_prior), ("range_scale_prior", args.range_scale_prior),
        ("filter_window", args.filter_window)) if value is not None}
    for item in args.option:
        name, _, value = item.partition("=")
        changed[name] = float(value)
    start = time.perf_counter()
    summaries, blunders = {}, []
    for scope in args.scopes:
        options = BlockOptions(navigation_scope=scope, **changed)
        rows = []
        for k in range(args.realizations):
            rows.append(block_statistics(args.seed + k, options))
            print(f"{scope} {args.seed + k}: σ̂0 = {rows[-1]['sigma0']:.3f}, alarms {rows[-1]['alarms']}", flush=True)
        summaries[scope] = summarize(rows)
        rng = np.random.default_rng(7)
        for k in range(args.blunders):
            blunders.append((scope, 5000 + k, planted_blunders(5000 + k, options, rng, "xy"[k % 2])))
            print(f"{scope} blunders {5000 + k}: {blunders[-1][2]}", flush=True)
    navigation = navigation_noise(filter_window=args.filter_window or 180.0)
    text = report(summaries, blunders, navigation, changed, args, time.perf_counter() - start)
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.append and args.out.exists():
        text = args.out.read_text() + "\n" + text
    args.out.write_text(text)


if __name__ == "__main__":
    main()

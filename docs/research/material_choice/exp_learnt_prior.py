"""Issue 38, round 13: the evidence blend's prior odds learnt from the set (empirical Bayes)
instead of the fixed ``c = 3`` (helper B).

Per scene x seed the scorecard's set row (``benchmarks/reconstruction_targets.py``: set 0 of
the run of 8 sets, the run's pooled library) is solved once: the default's set cube before
the blend (``set_model="material-pooled"`` with the run library), the choice the blend uses
(``sparse_choice`` with ``CHOICE_CANDIDATES``), and ``sparse-choice+run-library`` (the rival,
every candidate). The cubes are cached (``--cache``, default ``/work/notes/r13/B/cache``) and
every prior variant then costs seconds. ``c = 3`` on the cache reproduces the default's row.

Tuning rows: woven, halftone, glossy x seeds 0, 1; ``dark-still-life`` is held out and run
once at the end (``final --held-out``).

    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py cache     # all 8 rows
    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py tune [--cube full]
    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py oracle
    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py diagnose [--held-out]
    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py final     # tuning rows, table
    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_learnt_prior.py final --held-out

Variants of the texels' posterior ``pi_p = 1 / (1 + exp(Lambda_p - c))`` (``Lambda_p`` the
texel's pooled log-likelihood ratio of the choice over the default, bins included, as
``choice_log_odds`` with ``c = 0``):

- ``fixed c``: today's default is ``c = 3``;
- ``em m``: two classes (default holds / choice holds), ``exp(Lambda_p - m)`` the likelihood
  ratio after an optimism margin ``m`` (both fits saw the shots), the share ``pi_0`` of the
  default's class by EM over the set's texels; ``c = m + log(pi_0 / (1 - pi_0))``;
- ``gmm m``: a two-component Gaussian mixture of ``asinh(Lambda_p)`` by EM, ``pi_0`` the
  weight of the lower component; ``c = m + log(pi_0 / (1 - pi_0))``;
- ``gmm-spread k``: as ``gmm``, the margin from the lower component's spread: ``c`` such that
  a texel ``k`` standard deviations above the lower component's mean (in ``asinh``) is at
  even odds, plus ``log(pi_0 / (1 - pi_0))``;
- ``em-clip k``, ``em-temper T``: EM on ``Lambda_p`` clipped to ``+-k``, or on ``Lambda_p / T``
  (``c = T log(pi_0 / (1 - pi_0))``);
- ``true-share m`` (oracle): ``pi_0`` the share of texels the default truly fits better;
- ``oracle`` step: the best fixed ``c`` per row (truth-picked, a ceiling for any set-level c);
- ``diagnose`` step: the true share against EM's and the mixture's, and the AUC of ``Lambda``.

``final`` runs :data:`FINAL` (frozen after ``tune`` on the tuning rows: the brief's ``em 3``,
``em 0``, the learnt variant with the lowest worst ratio to today's default and the rival,
the best fixed ``c`` and the true-share oracle) with relit colour, and writes
``results_learnt_prior.json``. Results: ``docs/benchmarks_notes.md``,
``## reconstruction_run_library`` ("Thirteenth round, research").
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
import reconstruction_run_library as B  # noqa: E402
from reconstruction_hard import nrmse_per_pixel, relit_colour, scene_illuminant, statistics  # noqa: E402

from spectralize.nodes.reconstruction import inputs_from_xarray  # noqa: E402
from spectralize.nodes.reconstruction.endmember_library import DEFAULT_LIBRARY_SETS  # noqa: E402
from spectralize.nodes.reconstruction.estimators.evidence_blend import (  # noqa: E402
    CHOICE_CANDIDATES,
    DEFAULT_PRIOR_LOG_ODDS,
    MAX_LOG_ODDS,
    choice_log_odds,
)
from spectralize.nodes.reconstruction.estimators.sparse_choice import sparse_choice  # noqa: E402

SIZE = 48
TUNING = ("woven-fabric", "halftone-print", "glossy-mosaic")
HELD_OUT = "dark-still-life"
SEEDS = (0, 1)
CACHE = Path("/work/notes/r13/B/cache")


def stem(name: str, seed: int) -> Path:
    return CACHE / f"{name}_{SIZE}_{seed}"


def cache(name: str, seed: int) -> None:
    """Set 0's capture, the pooled cube, the blend's choice, the rival's cube and scores."""
    out = stem(name, seed)
    if Path(f"{out}.npz").exists():
        return
    started = time.perf_counter()
    sets = B.run_sets(name, seed, SIZE, DEFAULT_LIBRARY_SETS - 1)
    library = B.pooled_library(sets)
    capture = sets[0]
    default, _ = B.solve(capture, library)
    pooled_scores, pooled = B.solve(capture, library, set_model="material-pooled")
    rival, full = B.solve(capture, library, B.CHOICE)
    inputs = inputs_from_xarray(
        capture.rgb, capture.bands, capture.camera_matrix, illuminant=scene_illuminant(capture)
    )
    choice = sparse_choice(inputs, endmembers=library, candidates=CHOICE_CANDIDATES)
    np.savez(
        out,
        pooled=pooled.values,  # (image, wavelength, y, x)
        choice=np.moveaxis(choice, 0, 1),
        full=full.transpose(*pooled.dims).values,
    )
    with open(f"{out}_capture.pkl", "wb") as f:
        pickle.dump({"capture": capture, "dims": pooled.dims, "template": pooled}, f)
    Path(f"{out}_scores.json").write_text(
        json.dumps({"default": default, "pooled": pooled_scores, "rival": rival})
    )
    print(
        f"cached {name} {seed} in {time.perf_counter() - started:.0f} s: default "
        f"{default['median']:.5f}/{default['p95']:.4f}, rival {rival['median']:.5f}/"
        f"{rival['p95']:.4f}",
        flush=True,
    )


_LOADED: dict = {}


def load(name: str, seed: int) -> dict:
    if (name, seed) in _LOADED:
        return _LOADED[name, seed]
    out = stem(name, seed)
    with open(f"{out}_capture.pkl", "rb") as f:
        stored = pickle.load(f)
    capture = stored["capture"]
    arrays = np.load(f"{out}.npz")
    a, b = arrays["pooled"], arrays["choice"]
    inputs = inputs_from_xarray(
        capture.rgb, capture.bands, capture.camera_matrix, illuminant=scene_illuminant(capture)
    )
    lam = choice_log_odds(inputs, np.moveaxis(a, 0, 1), np.moveaxis(b, 0, 1), prior_log_odds=0.0)
    truth = capture.truth.values.astype(np.float64)
    d = {
        "name": name,
        "seed": seed,
        "capture": capture,
        "template": stored["template"],
        "a": a,
        "b": b,
        "full": arrays["full"],
        "lam": lam,
        "truth": truth,
        "scores": json.loads(Path(f"{out}_scores.json").read_text()),
        # per texel, is the choice truly better (summed squared error over the set)?
        "choice_better": ((b - truth) ** 2).sum(axis=(0, 1)) < ((a - truth) ** 2).sum(axis=(0, 1)),
    }
    _LOADED[name, seed] = d
    return d


def blend(d: dict, c: float, b: str = "b") -> np.ndarray:
    """The default's blend with prior log-odds ``c`` (as ``material_choice_blend``)."""
    log_odds = np.clip(d["lam"] - c, -MAX_LOG_ODDS, MAX_LOG_ODDS)
    weight = 1.0 - 1.0 / (1.0 + np.exp(log_odds))
    a = d["a"]
    return (a + weight * (d[b] - a)).astype(a.dtype)


def score(d: dict, cube: np.ndarray, relit: bool = False) -> dict:
    s = statistics(nrmse_per_pixel(cube, d["truth"]))
    if relit:
        rel, _ = relit_colour(d["template"].copy(data=cube), d["capture"])
        s["relit"] = {k: (rel[k]["median"], rel[k]["p95"]) for k in ("A", "FL11")}
    return s


def logit(p: float) -> float:
    p = float(np.clip(p, 1e-4, 1 - 1e-4))
    return float(np.log(p / (1 - p)))


def em_share(lam: np.ndarray, margin: float, iterations: int = 200) -> float:
    """``pi_0``: the share of texels the default holds, ``exp(Lambda - margin)`` the choice's
    likelihood ratio (EM over the set's texels)."""
    x = lam.ravel() - margin
    pi0 = 0.5
    for _ in range(iterations):
        r = 1.0 / (1.0 + np.exp(np.clip(logit(pi0) - x, -MAX_LOG_ODDS, MAX_LOG_ODDS)))
        new = float(np.clip(1.0 - r.mean(), 1e-4, 1 - 1e-4))
        if abs(new - pi0) < 1e-7:
            break
        pi0 = new
    return pi0


def gmm(lam: np.ndarray, iterations: int = 300) -> tuple[float, float, float, float, float]:
    """Two-component Gaussian mixture of ``asinh(Lambda)``: ``pi_0, mu_0, s_0, mu_1, s_1``
    (component 0 the lower)."""
    x = np.arcsinh(lam.ravel())
    lo, hi = np.percentile(x, [25, 75])
    w, mu, s = np.array([0.5, 0.5]), np.array([lo, hi]), np.array([x.std(), x.std()]) + 1e-6
    for _ in range(iterations):
        dens = w / s * np.exp(-0.5 * ((x[:, None] - mu) / s) ** 2)
        r = dens / np.maximum(dens.sum(1, keepdims=True), 1e-300)
        n = r.sum(0)
        w, mu = n / n.sum(), (r * x[:, None]).sum(0) / np.maximum(n, 1e-12)
        s = np.sqrt((r * (x[:, None] - mu) ** 2).sum(0) / np.maximum(n, 1e-12)) + 1e-3
    order = np.argsort(mu)
    w, mu, s = w[order], mu[order], s[order]
    return float(w[0]), float(mu[0]), float(s[0]), float(mu[1]), float(s[1])


def prior(d: dict, variant: str) -> float:
    """The variant's ``c`` for the set."""
    kind, _, arg = variant.partition(" ")
    if kind == "fixed":
        return float(arg)
    if kind == "em":
        m = float(arg)
        return m + logit(em_share(d["lam"], m))
    if kind == "em-clip":  # EM on Lambda clipped to +-k (a few texels' tails do not decide)
        k = float(arg)
        return logit(em_share(np.clip(d["lam"], -k, k), 0.0))
    if kind == "em-temper":  # EM on Lambda / T (the optimism as a temperature), c = T logit
        t = float(arg)
        return t * logit(em_share(d["lam"] / t, 0.0))
    if kind == "gmm":
        return float(arg) + logit(gmm(d["lam"])[0])
    if kind == "gmm-spread":
        pi0, mu0, s0, _, _ = gmm(d["lam"])
        return float(np.sinh(mu0 + float(arg) * s0)) + logit(pi0)
    if kind == "true-share":  # oracle: pi_0 the share of texels the default truly fits better
        return float(arg) + logit(1.0 - float(d["choice_better"].mean()))
    raise SystemExit(f"unknown variant {variant!r}")


def auc(score_: np.ndarray, positive: np.ndarray) -> float:
    """Probability that a texel the choice truly fits better has the larger ``Lambda``."""
    from scipy.stats import rankdata

    r = rankdata(score_.ravel())
    pos = positive.ravel()
    n1, n0 = pos.sum(), (~pos).sum()
    return float((r[pos].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def diagnose(held_out: bool = False) -> None:
    """Per row: the true share of the choice's texels against EM's and the mixture's, and how
    well ``Lambda`` ranks the texels the choice truly fits better (AUC)."""
    for case in rows(held_out):
        d = load(*case)
        lam, better = d["lam"], d["choice_better"]
        print(
            f"{case}: choice truly better on {better.mean():.3f}; EM (m=0) 1 - pi_0 "
            f"{1 - em_share(lam, 0.0):.3f}; mixture 1 - pi_0 {1 - gmm(lam)[0]:.3f}; AUC of Lambda "
            f"{auc(lam, better):.3f}; median Lambda where the choice / the default is better "
            f"{np.median(lam[better]):.2f} / {np.median(lam[~better]):.2f}; share Lambda > 0 "
            f"{np.mean(lam > 0):.3f}",
            flush=True,
        )


FIXED = tuple(f"fixed {c}" for c in (-2, -1, 0, 1, 2, 3, 4, 6, 10))
LEARNT = (
    *(f"em {m}" for m in (0, 1, 2, 3, 4, 6)),
    *(f"gmm {m}" for m in (0, 1, 2, 3, 4)),
    *(f"gmm-spread {k}" for k in (0, 0.5, 1, 1.5, 2, 3)),
)


def rows(held_out: bool) -> list[tuple[str, int]]:
    return [(HELD_OUT, s) for s in SEEDS] if held_out else [(n, s) for n in TUNING for s in SEEDS]


def oracle_c(held_out: bool = False) -> None:
    """Per row and choice cube, the fixed ``c`` of the lowest median and of the lowest p95."""
    grid = np.arange(-6.0, 10.01, 0.5)
    for case in rows(held_out):
        d = load(*case)
        rival = d["scores"]["rival"]
        for cube in ("b", "full"):
            s = [score(d, blend(d, c, cube)) for c in grid]
            med = [x["median"] for x in s]
            p95 = [x["p95"] for x in s]
            both = [
                c
                for c, x in zip(grid, s, strict=True)
                if x["median"] < min(rival["median"], d["scores"]["default"]["median"])
                and x["p95"] < min(rival["p95"], d["scores"]["default"]["p95"])
            ]
            print(
                f"{case} choice {cube:4s}: best median c={grid[np.argmin(med)]:.1f} "
                f"{min(med):.4f}, best p95 c={grid[np.argmin(p95)]:.1f} {min(p95):.4f}; c beating "
                f"default and rival at both: {both}; rival {rival['median']:.4f}/{rival['p95']:.4f}",
                flush=True,
            )


def tune(cube: str = "b", variants: list[str] | None = None) -> None:
    """Every variant on the tuning rows: its c, ratios to today's default and to the rival."""
    cases = rows(False)
    for case in cases:
        d = load(*case)
        check = score(d, blend(d, DEFAULT_PRIOR_LOG_ODDS))
        stored = d["scores"]["default"]
        print(
            f"{case}: c=3 on the cache {check['median']:.5f}/{check['p95']:.5f}, the default "
            f"solved {stored['median']:.5f}/{stored['p95']:.5f}; choice truly better on "
            f"{d['choice_better'].mean():.3f} of texels; Lambda quantiles 10/50/90 "
            f"{np.round(np.percentile(d['lam'], [10, 50, 90]), 1)}; gmm {np.round(gmm(d['lam']), 2)}",
            flush=True,
        )
    for variant in variants or (*FIXED, *LEARNT):
        line, worst = [], 0.0
        for case in cases:
            d = load(*case)
            c = prior(d, variant)
            s = score(d, blend(d, c, cube))
            base, rival = score(d, blend(d, DEFAULT_PRIOR_LOG_ODDS)), d["scores"]["rival"]
            ratios = [s[k] / base[k] for k in ("median", "p95")] + [
                s[k] / rival[k] for k in ("median", "p95")
            ]
            worst = max(worst, *ratios)
            line.append(f"{case[0][:5]}{case[1]} c={c:5.2f} {s['median']:.4f}/{s['p95']:.3f}")
        print(f"{variant:14s} worst ratio {worst:.3f} | " + " | ".join(line), flush=True)


FINAL = (
    ("em 3", "b"),  # the brief's: EM share, Kass-Raftery margin kept
    ("em 0", "b"),  # EM share, no margin
    ("gmm-spread 0", "b"),  # the learnt variant with the lowest worst ratio on the tuning rows
    ("fixed -1", "b"),  # reference: the best fixed c on the tuning rows (not learnt)
    ("true-share -1", "b"),  # oracle: the true share of the choice's texels, margin -1
)
"""The variants of the table, frozen after ``tune`` (dark-still-life not seen)."""
RESULTS = HERE / "results_learnt_prior.json"


def relit_pair(relit: dict) -> dict:
    return {k: (relit[k]["median"], relit[k]["p95"]) for k in ("A", "FL11")}


def final(held_out: bool) -> None:
    """The table: today's default (c = 3), the rival and :data:`FINAL` per row."""
    table = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    keys = ("median", "p95", "fraction_under_0.03")
    for case in rows(held_out):
        d = load(*case)
        rival = d["scores"]["rival"]
        entries = {
            "default (c = 3)": score(d, blend(d, DEFAULT_PRIOR_LOG_ODDS), relit=True),
            "sparse-choice+run-library": {
                **{k: rival[k] for k in keys},
                "relit": relit_pair(rival["relit_de2000"]),
            },
        }
        stored = d["scores"]["default"]
        assert entries["default (c = 3)"]["median"] == stored["median"], (case, stored)
        for variant, cube in FINAL:
            c = prior(d, variant)
            entry = score(d, blend(d, c, cube), relit=True)
            entry["c"] = round(c, 3)
            entry["beats_both"] = all(
                entry[k] < entries[r][k]
                for k in ("median", "p95")
                for r in ("default (c = 3)", "sparse-choice+run-library")
            )
            entries[variant] = entry
        table[f"{case[0]} {case[1]}"] = entries
        for name, e in entries.items():
            relit = e["relit"]
            print(
                f"| {case[0]} {case[1]} | {name} | {e.get('c', '')} | {e['median']:.5f} | "
                f"{e['p95']:.4f} | {e['fraction_under_0.03']:.3f} | {relit['A'][0]:.2f} / "
                f"{relit['A'][1]:.1f} | {relit['FL11'][0]:.2f} / {relit['FL11'][1]:.1f} | "
                f"{e.get('beats_both', '')} |",
                flush=True,
            )
    RESULTS.write_text(json.dumps(table, indent=1) + "\n")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("step", choices=("cache", "tune", "oracle", "diagnose", "final"))
    parser.add_argument("--cube", default="b", choices=("b", "full"))
    parser.add_argument("--held-out", action="store_true")
    parser.add_argument("--variants", nargs="*", default=[])
    args = parser.parse_args()
    if args.step == "cache":
        CACHE.mkdir(parents=True, exist_ok=True)
        for case in rows(False) + rows(True):
            cache(*case)
    elif args.step == "tune":
        tune(args.cube, args.variants)
    elif args.step == "final":
        final(args.held_out)
    elif args.step == "diagnose":
        diagnose(args.held_out)
    elif args.step == "oracle":
        oracle_c()

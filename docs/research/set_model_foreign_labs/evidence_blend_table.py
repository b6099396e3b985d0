"""Table of evidence_blend_labs.py's logs: python evidence_blend_table.py LOG...

With --warm: evidence_blend_warm.py's logs (warm_table). Otherwise, per lab, groups (oracle,
calibrated) and camera: median / p95 of 'independent',
'material-pooled' and the default ('evidence-blend'), and default / material-pooled; a ratio
over 1.02 is marked '!'.
"""

import json
import sys
from pathlib import Path

HELD_OUT = ("sigma-paired", "sigma-paired-white", "sigma-paired-falloff", "gaussian-falloff")


def result(log: Path) -> dict:
    """The RESULT json (last line) of one lab's log."""
    lines = [line for line in log.read_text().splitlines() if line.startswith("RESULT ")]
    return json.loads(lines[-1][len("RESULT ") :])


def main(logs: list[str]) -> None:
    print(
        "| lab | groups | camera | independent | material-pooled | default (evidence-blend) "
        "| default / pooled median, p95 |"
    )
    print("|---|---|---|---|---|---|---|")
    worst: list[tuple[float, str]] = []
    for path in logs:
        lab = Path(path).stem
        out = result(Path(path))
        for groups in ("oracle", "cal", "oracle+storelib"):
            if f"{groups} default" not in out:
                continue
            pooled, default = out[f"{groups} material-pooled"], out[f"{groups} default"]
            assert default["seed_set_model"] == "evidence-blend", (lab, groups, default)
            assert default["seed_endmembers"] == "run", (lab, groups, default)
            independent = out.get(f"{groups} independent", {"row": {}})["row"]
            nolib = out.get(f"{groups} nolib default", {"row": {}})["row"]
            for camera, (dm, dp, _) in default["row"].items():
                pm, pp, _ = pooled["row"][camera]
                rm, rp = dm / pm, dp / pp
                im = independent.get(camera)
                ind = f"{im[0]:.4f} / {im[1]:.4f}" if im else "-"
                nm = nolib.get(camera)
                nol = f"{nm[0]:.4f} / {nm[1]:.4f}" if nm else "-"
                mark = lambda r: f"{r:.3f}{' !' if r > 1.02 else ''}"  # noqa: E731
                name = lab + (" (held out)" if lab in HELD_OUT else "")
                print(
                    f"| {name} | {groups} | {camera} | {ind} | {pm:.4f} / {pp:.4f} "
                    f"| {dm:.4f} / {dp:.4f} | {mark(rm)}, {mark(rp)} | {nol} |"
                )
                worst += [(rm, f"{lab} {groups} {camera} median"), (rp, f"{lab} {groups} {camera} p95")]
    worst.sort(reverse=True)
    print("\nlargest default / material-pooled:", ", ".join(f"{n} {r:.3f}" for r, n in worst[:6]))
    print("smallest:", ", ".join(f"{n} {r:.3f}" for r, n in worst[-4:]))


def warm_table(logs: list[str]) -> None:
    """evidence_blend_warm.py's crossings: per lab and groups, the largest (and smallest) ratio
    over the cameras of median and p95 of (1) the set step alone on the seed set's own images
    (default / pooled, same inputs), (2) the set step alone on the other sets (default /
    pooled sets, both warm-started from the pooled seed), (3) the warm start alone (pooled sets
    from the default's seed / from the pooled seed), (4) both (the default / pooled)."""
    print("| lab | groups | step on the seed set | step on the other sets | warm start | both |")
    print("|---|---|---|---|---|---|")
    for path in logs:
        rows = {}
        for line in Path(path).read_text().splitlines():
            if line.startswith("sets "):
                words = line.split(maxsplit=4)
                rows[(words[1], words[3])] = json.loads(words[4])
        lab, groups = Path(path).stem.removeprefix("warm_").rsplit("_", 1)
        if len(rows) < 4:
            print(f"| {lab} | {groups} | (incomplete) | | | |")
            continue

        def span(num, den, suffix):
            """min-max over the cameras of median and p95 ratios, keys ending in suffix
            ('' : the cameras' whole rows)."""
            keys = [k for k in num if k in den and (k.endswith(suffix) if suffix else k[-1] != ")")]
            if not keys:
                return "-"
            med = [num[k][0] / den[k][0] for k in keys]
            p95 = [num[k][1] / den[k][1] for k in keys]
            return f"{min(med):.3f}-{max(med):.3f} / {min(p95):.3f}-{max(p95):.3f}"

        pp, pd = rows[("pooled", "pooled")], rows[("pooled", "default")]
        dp, dd = rows[("default", "pooled")], rows[("default", "default")]
        name = lab + (" (held out)" if lab in HELD_OUT else "")
        print(
            f"| {name} | {groups} | {span(dd, pp, '(seed)')} | {span(dp, pp, '(not seed)')} "
            f"| {span(pd, pp, '(not seed)')} | {span(dd, pp, '')} |"
        )


if __name__ == "__main__":
    if sys.argv[1:2] == ["--warm"]:
        warm_table(sys.argv[2:])
    else:
        main(sys.argv[1:])

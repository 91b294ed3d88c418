"""The diagnostics loop on the mock robot, one hidden effect at a time: the table in docs/DIAGNOSTICS.md.

For each effect (and none, and a pair): `naocal simulate` with it hidden, `naocal diagnose` (top candidate, p),
`naocal identify --effects <it>` (RMS and cross-validated RMS against the noise floor), `naocal diagnose --effects
<it>` (anything left?). Checks the issue's criteria (top and significant; RMS and CV RMS within 20 % of the floor;
nothing significant once added) and prints one row per case. About 40 s per case on 2 cores.

    python benchmarks/mock_effects_table.py [--seed 7] [--out /tmp/naocal_effects] [--only time_lag,backlash]
"""

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from naocal.tools.cli import main  # noqa: E402

SIZES = {"elasticity": 0.03, "backlash": 0.012, "link_lengths": 0.0025, "head_offsets": 0.017,
         "intrinsics": 10.0, "distortion": 0.08, "time_lag": 0.04}
MARGIN = 1.2


def run_json(*args):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main([*map(str, args), "--json"])
    if code != 0:
        raise SystemExit(f"naocal {' '.join(map(str, args))} exited {code}")
    return json.loads(out.getvalue())


def total(xy):
    return (0.5 * (xy[0] ** 2 + xy[1] ** 2)) ** 0.5


def simulate(root: Path, seed: int, effects) -> Path:
    out = root / ("_".join(effects) or "none")
    if not (out / "truth.json").exists():
        args = ["simulate", "--out", str(out), "--seed", str(seed), "--no-progress", "--mock", "ideal"]
        for e in effects:
            args += ["--effect", f"{e}={SIZES[e]}"]
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(args) == 0, args
    return out


def case(root: Path, seed: int, effects) -> tuple[str, bool]:
    t0 = time.perf_counter()
    dataset = simulate(root, seed, effects)
    base = run_json("diagnose", dataset)
    floor = base["noise_px"]
    if not effects:
        quiet = not any(c["significant"] for c in base["candidates"])
        low = min(c["p_value"] for c in base["candidates"] if c["p_value"] is not None)
        ok = quiet and total(base["rms_px"]) < MARGIN * floor
        return (f"| none | {total(base['rms_px']):.3f} ({total(base['rms_px']) / floor:.2f} x floor) | nothing "
                f"significant (lowest p {low:.2f}) | | {floor:.3f} |", ok)
    added, names, ok = [], [], True
    for _ in effects:  # add the top candidate, diagnose again
        diagnosis = run_json("diagnose", dataset, *(["--effects", ",".join(added)] if added else []))
        top = diagnosis["candidates"][0]
        ok &= top["significant"] and top["effect"] in effects and top["effect"] not in added
        names.append(f"{top['effect']}, {top['p_value']:.0e}")
        added.append(top["effect"])
    fit = run_json("identify", dataset, "--effects", ",".join(added))
    after = run_json("diagnose", dataset, "--effects", ",".join(added))
    rms, cv = total(fit["rms_px"]), total(fit["cv_rms_px"])
    ok &= rms < MARGIN * floor and cv < MARGIN * floor and not any(c["significant"] for c in after["candidates"])
    row = (f"| {' + '.join(f'{e} {SIZES[e]:g}' for e in effects)} | {total(base['rms_px']):.3f} | "
           f"{'; then '.join(names)} | {rms:.3f} / {cv:.3f} ({rms / floor:.2f} / {cv / floor:.2f} x floor) | "
           f"{floor:.3f} |")
    print(f"  ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return row, ok


def main_cli():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--out", type=Path, default=Path("/tmp/naocal_effects"))
    parser.add_argument("--only", default="", help="comma-separated cases (effect names, none, pair)")
    args = parser.parse_args()
    cases = [()] + [(e,) for e in SIZES] + [("backlash", "distortion")]
    if args.only:
        wanted = set(args.only.split(","))
        cases = [c for c in cases if ("_".join(c) or "none") in wanted or ("pair" in wanted and len(c) == 2)]
    args.out.mkdir(parents=True, exist_ok=True)
    print("| hidden | base RMS (px) | diagnose: top, p | with it: RMS / CV RMS (px) | floor (px) |")
    print("|---|---|---|---|---|")
    failures = []
    for effects in cases:
        row, ok = case(args.out, args.seed, effects)
        print(row + ("" if ok else "  <- FAILS the issue's criteria"), flush=True)
        if not ok:
            failures.append("_".join(effects) or "none")
    print(f"{len(cases) - len(failures)} of {len(cases)} cases meet the criteria" +
          (f"; failing: {', '.join(failures)}" if failures else ""))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main_cli())

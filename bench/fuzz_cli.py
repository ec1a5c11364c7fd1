"""The long fuzz run of the ``zcut`` command line: N hostile cases, every one run as the real command.

    .venv/bin/python bench/fuzz_cli.py --cases 10000 --seed 1 --jobs 2

Cases come from the seeded generators of ``tests/fuzz/fuzzgen.py`` (MCAP bytes and structure,
compression bombs, PointCloud2/Image/CameraInfo semantics, PCD/PLY headers and bodies, command
lines, paths, config files, label files), in the shares of ``fuzzgen.WEIGHTS``; each runs under a
time and a memory cap (``tests/fuzz/fuzzlib.py``: a warm server forks one child per case, or
``--mode subprocess``) and is classified as clean / traceback / hang / crash / memory / loss-exit0
/ input-modified / bad-exit / leftover. Prints the table generator x class, then every distinct
finding (most frequent first) with its reproducer, kept under ``--keep`` (default
/tmp/fuzz_findings): ``cd DIR && zcut ARGS`` is in ``DIR.cmd.sh``.

``--only GEN[,GEN]`` runs some generators only; ``--ids`` reruns given case ids (e.g. the ones a
previous run listed). The per-case cost (wall, CPU of the child, peak RSS) is printed at the end.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent / "tests" / "fuzz"), str(HERE.parent)]

import fuzzgen
import fuzzlib


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--mode", choices=("fork", "subprocess"), default="fork")
    ap.add_argument("--timeout", type=float, default=fuzzlib.DEFAULT_TIMEOUT_S, help="seconds a case (default 30)")
    ap.add_argument("--mem-gb", type=float, default=fuzzlib.DEFAULT_MEM_BYTES / 2**30,
                    help="resident memory of a case, GiB (default 3)")
    ap.add_argument("--as-gb", type=float, default=fuzzlib.DEFAULT_AS_BYTES / 2**30,
                    help="address space a case may add to the warm process (RLIMIT_AS), GiB (default 8)")
    ap.add_argument("--only", default=None, help="comma-separated generators")
    ap.add_argument("--ids", nargs="*", default=None, help="rerun these case ids")
    ap.add_argument("--keep", type=Path, default=Path("/tmp/fuzz_findings"), help="where reproducers go")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder (default: a temporary one)")
    ap.add_argument("--corpus", type=Path, default=None, help="corpus folder (default: built in the scratch folder)")
    ap.add_argument("--progress", type=int, default=500, help="print a line every N cases")
    args = ap.parse_args(argv)
    sys.stdout.reconfigure(errors="backslashreplace")  # file names from hostile command lines

    work = args.work or Path(tempfile.mkdtemp(prefix="zcut_fuzz_"))
    t0 = time.perf_counter()
    if args.corpus is not None and (args.corpus / "corpus.json").is_file():
        # a kept corpus: compile the kernels anyway (a changed source would otherwise compile in the cases)
        import subprocess

        env = dict(os.environ, PYTHONPATH=str(fuzzlib.REPO))
        subprocess.run([fuzzlib.PYTHON, "-m", "replay.warmup"], env=env, cwd=str(fuzzlib.REPO), check=True,
                       capture_output=True)
    corpus = fuzzgen.ensure_corpus(args.corpus or work / "corpus")
    print(f"corpus: {corpus.dir} ({len(corpus.files)} files, {time.perf_counter() - t0:.1f} s)", flush=True)
    if args.ids:
        cases = []
        for cid in args.ids:
            g, s, k = cid.rsplit("-", 2)
            cases.append(fuzzgen.make_case(corpus, g, int(s), int(k)))
        todo = iter(cases)
        total = len(cases)
    else:
        counts = fuzzgen.scaled(args.cases)
        if args.only:
            keep = set(args.only.split(","))
            unknown = keep - set(fuzzgen.GENERATORS)
            if unknown:
                ap.error(f"unknown generators: {', '.join(sorted(unknown))}")
            counts = {g: n for g, n in counts.items() if g in keep}
            scale = args.cases / max(sum(counts.values()), 1)
            counts = {g: max(1, round(n * scale)) for g, n in counts.items()}
        total = sum(counts.values())
        todo = fuzzgen.make_cases(corpus, counts, args.seed)
    outcomes: list[fuzzlib.Outcome] = []
    t_run = time.perf_counter()

    def progress(o: fuzzlib.Outcome) -> None:
        outcomes.append(o)
        if o.klass != "clean":
            print(f"  {o.klass:<14} {o.case.id}: {o.detail[:150]}", flush=True)
        if len(outcomes) % args.progress == 0:
            rate = len(outcomes) / (time.perf_counter() - t_run)
            print(f"[{len(outcomes)}/{total}] {rate:.2f} cases/s", flush=True)

    for _ in fuzzlib.run_cases(todo, work / "cases", jobs=args.jobs, mode=args.mode, timeout_s=args.timeout,
                               mem_bytes=int(args.mem_gb * 2**30), as_bytes=int(args.as_gb * 2**30), keep=args.keep, on_outcome=progress):
        pass
    wall = time.perf_counter() - t_run
    print()
    print(f"{len(outcomes)} cases, seed {args.seed}, mode {args.mode}, {args.jobs} jobs, {wall:.0f} s wall")
    print(fuzzlib.table(outcomes))
    rcs: dict[str, dict[str, int]] = {}
    for o in outcomes:
        key = "signal" if o.rc is None else f"exit {o.rc}"
        rcs.setdefault(o.case.generator, {}).setdefault(key, 0)
        rcs[o.case.generator][key] += 1
    print("\nexit statuses: " + "; ".join(f"{g} " + ", ".join(f"{k} {n}" for k, n in sorted(v.items()))
                                          for g, v in sorted(rcs.items())))
    cpu = [o.cpu_s for o in outcomes]
    walls = [o.wall_s for o in outcomes]
    if outcomes:
        print(f"\nper case: wall median {statistics.median(walls):.3f} s, mean {statistics.mean(walls):.3f} s; "
              f"child CPU median {statistics.median(cpu):.3f} s, mean {statistics.mean(cpu):.3f} s, "
              f"total {sum(cpu):.0f} s; peak RSS max {max(o.maxrss_mb for o in outcomes):.0f} MB")
        by_gen: dict[str, list[float]] = {}
        for o in outcomes:
            by_gen.setdefault(o.case.generator, []).append(o.cpu_s)
        print("child CPU per case by generator (mean s): "
              + ", ".join(f"{g} {statistics.mean(v):.2f}" for g, v in sorted(by_gen.items())))
    groups = fuzzlib.findings(outcomes)
    if groups:
        print(f"\n{len(groups)} distinct findings (most frequent first); reproducers in {args.keep}/<id>.cmd.sh")
        for sig, os_ in groups:
            first = min(os_, key=lambda o: sum(len(v) for v in o.case.files.values()))
            print(f"\n[{len(os_)}x] {sig}")
            print(f"    e.g. {first.case.id}: {first.case.what[:160]}")
            print(f"    sh {args.keep}/{first.case.id}.cmd.sh   # {first.case.command_line()[:160]}")
            print(f"    -> {first.detail[:200]}")
            print("    ids: " + " ".join(o.case.id for o in os_[:12]) + (" …" if len(os_) > 12 else ""))
    else:
        print("\nevery case clean")
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if not groups else 1


if __name__ == "__main__":
    sys.exit(main())

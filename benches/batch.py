"""Many pairs: register_many against a loop of register, a process pool, Dask and `sdfreg batch`.

    scripts/python-env                          # once: the venv with the wheel, dask (and ray)
    cargo build --release -p sdfreg-cli         # for the `sdfreg batch` row
    .venv/bin/python benches/batch.py --data ../shared/data [--pairs 64] [--protocol clean]
    .venv/bin/python benches/batch.py --stress 10000     # 10⁴ rows through `sdfreg batch`
    .venv/bin/python benches/batch.py --laz 4 --data ../shared/data   # large LAZ pairs
    .venv/bin/python benches/batch.py --models 60 --data ../shared/data   # many stored models

Throughput (the default): the pairs of the paper's protocol (`sdfreg eval --write-pairs` over
ModelNet40 in --data; procedural blobs with a message when it is missing), registered in one
run five ways, each with the default settings and seed 0:
- a loop of `sdfreg.register(source, target)` (threads=0: each call on every core);
- `sdfreg.register_many(pairs)` (one pair per worker, one worker per core);
- a `ProcessPoolExecutor` with one process per core, `register(..., threads=1)` in each;
- `sdfreg.dask.register_pairs` on a `LocalCluster(n_workers=cores, threads_per_worker=1)` (the
  cluster's start-up not counted); the scheduler's overhead per pair is its time less
  register_many's, over the pairs, and also measured with empty tasks;
- `sdfreg batch PAIRS.csv` (reading the files included).
Prints pairs per second for each, the ratios to the loop, and checks that every way gives the
same transformations as the loop, bit for bit.

--stress N: N rows (16 distinct 512-point sources, against one stored model) through
`sdfreg batch`: runs 1/10 of them and all of them, each in a fresh output, and prints each run's
peak RSS (memory stays flat when the second is no larger); then a third run killed halfway and
resumed, checking every row is in the output exactly once.

--laz N: N pairs of LiDAR-sized LAZ files through `sdfreg batch`, where reading the files costs
as much as registering them: each target is the frames of `lidar/kitti00_frames` tiled 18 times
on a 3 × 6 grid 200 m apart, each tile turned its own way (about 2.2 million points), its source
the same points turned 2.9° about z and moved (0.3, -0.2, 0.05) m. Prints the wall time, the CPU time of the
`sdfreg batch` process (its ratio to the wall time is how many cores were busy) and the worst
errors. Two builds are compared by running this with SDFREG_CLI set to each.

--models N: 2N rows through `sdfreg batch`, against N stored models (each its own file, a copy
of the model of one frame of `lidar/kitti00_frames`), each model named by two rows; the sources
are the frames turned 1.5° about z and moved (0.2, -0.1, 0.05) m. Runs two files: each model's
rows together, and apart (every model's first row, then every second row). Prints the wall
time, CPU time, peak RSS and worst errors of each, as --laz does: a batch that keeps every model
it has loaded grows with N, and one whose two workers start on the same fresh model waits.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import sdfreg
from common import blob, euler_xyz, pose_errors, rotation_about

ROOT = Path(__file__).resolve().parents[1]
CLI = Path(os.environ.get("SDFREG_CLI", ROOT / "target/release/sdfreg"))


def write_pairs(data: Path, protocol: str, n: int, out: Path) -> list[tuple[Path, Path, np.ndarray]]:
    """The protocol's pairs as files (source.ply, target.ply, the truth)."""
    shapes = data / "modelnet40-half1"
    if shapes.is_dir() and CLI.exists():
        subprocess.run(
            [CLI, "eval", "--shapes", shapes, "--protocol", protocol, "--pairs", str(n),
             "--write-pairs", out, "--pairs-only"],
            check=True, capture_output=True,
        )
        listing = json.loads((out / "pairs.json").read_text())["pairs"]
        return [
            (out / p["dir"] / "source.ply", out / p["dir"] / "target.ply", np.array(p["t_target_source"]))
            for p in listing
        ]
    print(f"batch.py: no {shapes} (or no {CLI}): procedural blobs under the paper's protocol instead")
    pairs = []
    for k in range(n):
        rng = np.random.default_rng(k)
        target = blob(1024, rng)
        truth = np.eye(4)
        truth[:3, :3], truth[:3, 3] = euler_xyz(rng.uniform(0, 45, 3)), rng.uniform(-0.5, 0.5, 3)
        source = (target - truth[:3, 3]) @ truth[:3, :3]
        d = out / f"{k:03d}"
        d.mkdir(parents=True)
        sdfreg.write_point_cloud(d / "source.ply", source)
        sdfreg.write_point_cloud(d / "target.ply", target)
        pairs.append((d / "source.ply", d / "target.ply", truth))
    return pairs


def register_alone(pair: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    return sdfreg.register(*pair, threads=1).transformation


def noop(x: int) -> int:
    return x


def throughput(args: argparse.Namespace) -> None:
    from dask.distributed import Client, LocalCluster

    import sdfreg.dask

    cores = os.cpu_count() or 1
    work = Path(tempfile.mkdtemp(prefix="sdfreg-batch-bench-"))
    try:
        files = write_pairs(args.data, args.protocol, args.pairs, work / "pairs")
        clouds = [(sdfreg.read_point_cloud(s), sdfreg.read_point_cloud(t)) for s, t, _ in files]
        n = len(clouds)
        rows: dict[str, float] = {}

        start = time.perf_counter()
        loop = [sdfreg.register(s, t).transformation for s, t in clouds]
        rows["loop of register (threads=0)"] = time.perf_counter() - start

        start = time.perf_counter()
        many = sdfreg.register_many(clouds)
        rows["register_many"] = time.perf_counter() - start

        start = time.perf_counter()
        with concurrent.futures.ProcessPoolExecutor(cores) as pool:
            pooled = list(pool.map(register_alone, clouds))
        rows[f"process pool ({cores} processes)"] = time.perf_counter() - start

        cluster = LocalCluster(n_workers=cores, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        with Client(cluster) as client:
            client.gather(client.map(noop, range(cores)))  # workers warm
            start = time.perf_counter()
            client.gather(client.map(noop, range(1000), pure=False))
            empty = (time.perf_counter() - start) / 1000
            start = time.perf_counter()
            dasked = sdfreg.dask.register_pairs(client, clouds)
            rows[f"dask LocalCluster ({cores} workers)"] = time.perf_counter() - start
        cluster.close()

        csv = work / "pairs.csv"
        csv.write_text("".join(f"{s},{t}\n" for s, t, _ in files))
        start = time.perf_counter()
        run = subprocess.run([CLI, "batch", csv, "--output", work / "out.jsonl"], capture_output=True, text=True)
        rows["sdfreg batch (CLI)"] = time.perf_counter() - start
        if run.returncode != 0:
            sys.exit(f"sdfreg batch failed: {run.stderr}")
        records = [json.loads(l) for l in (work / "out.jsonl").read_text().splitlines()[1:]]
        batched = [np.array(r["transformation"]) for r in sorted(records, key=lambda r: r["row"])]

        for name, got in [("register_many", [r.transformation for r in many]), ("process pool", pooled),
                          ("dask", [r.transformation for r in dasked]), ("sdfreg batch", batched)]:
            same = all(np.array_equal(a, b) for a, b in zip(loop, got)) and len(got) == n
            print(f"{name:>14}: transformations {'bit-identical to' if same else 'DIFFER from'} the loop's")
        errors = [pose_errors(m, truth)[0] for m, (_, _, truth) in zip(loop, files)]
        print(f"{n} pairs ({args.protocol}), mean rotation error {np.mean(errors):.3f}°, "
              f"{sum(e < 5 for e in errors)}/{n} under 5°; {cores} cores, CPU flags: {cpu_flags()}")
        base = rows["loop of register (threads=0)"]
        print(f"{'way':<34} {'s':>7} {'pairs/s':>8} {'× loop':>7}")
        for name, seconds in rows.items():
            print(f"{name:<34} {seconds:7.1f} {n / seconds:8.2f} {base / seconds:7.2f}")
        dask_s = rows[f"dask LocalCluster ({cores} workers)"]
        print(f"dask overhead per pair: {(dask_s - rows['register_many']) / n * 1e3:.1f} ms against register_many; "
              f"an empty task costs {empty * 1e3:.2f} ms")
    finally:
        shutil.rmtree(work)


def cpu_flags() -> str:
    try:
        flags = next(l for l in Path("/proc/cpuinfo").read_text().splitlines() if l.startswith("flags")).split()
    except (OSError, StopIteration):
        return "unknown"
    return " ".join(f for f in ("avx512f", "avx2", "fma") if f in flags) or "none of avx512f avx2 fma"


def batch_run(csv: Path, out: Path, kill_after: int | None = None) -> tuple[float, float, float]:
    """Runs `sdfreg batch`; (seconds, CPU seconds, peak RSS in MiB) of that child alone (its own
    rusage, from wait4). With kill_after, SIGKILLs it once that many records are in the output."""
    start = time.perf_counter()
    proc = subprocess.Popen([CLI, "batch", csv, "--output", out], stderr=subprocess.DEVNULL)
    killed = kill_after is None
    while True:
        # Reaped here, not by Popen, to read the child's own rusage.
        pid, status, usage = os.wait4(proc.pid, 0 if killed else os.WNOHANG)
        if pid:
            break
        if out.exists() and out.read_bytes().count(b"\n") > kill_after:
            os.kill(proc.pid, signal.SIGKILL)
            killed = True
        else:
            time.sleep(0.05)
    seconds = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if kill_after is None and proc.returncode != 0:
        sys.exit(f"sdfreg batch exited {proc.returncode}")
    return seconds, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def stress(n: int) -> None:
    work = Path(tempfile.mkdtemp(prefix="sdfreg-batch-stress-"))
    try:
        rng = np.random.default_rng(0)
        target = blob(4096, rng)
        sdfreg.fit(target).save(work / "model.sdfm")
        for k in range(16):
            truth_r = euler_xyz(rng.uniform(0, 45, 3))
            source = (blob(512, np.random.default_rng(100 + k)) - rng.uniform(-0.5, 0.5, 3)) @ truth_r
            sdfreg.write_point_cloud(work / f"s{k:02d}.ply", source)
        for rows in (n // 10, n):
            csv = work / f"pairs{rows}.csv"
            csv.write_text("".join(f"s{k % 16:02d}.ply,model.sdfm\n" for k in range(rows)))
            seconds, _, rss = batch_run(csv, work / f"out{rows}.jsonl")
            print(f"{rows:>6} rows: {seconds:6.1f} s, {rows / seconds:6.1f} pairs/s, peak RSS {rss:6.1f} MiB")
        csv = work / f"pairs{n}.csv"
        out = work / "killed.jsonl"
        seconds, _, _ = batch_run(csv, out, kill_after=n // 2)
        done = out.read_bytes().count(b"\n") - 1
        print(f"killed after {seconds:.1f} s with {done} rows in the output; resuming …")
        run = subprocess.run([CLI, "batch", csv, "--output", out], capture_output=True, text=True)
        print("  " + run.stderr.strip().replace("\n", "\n  "))
        lines = out.read_text().splitlines()[1:]
        row_ids = [json.loads(l)["row"] for l in lines]
        ok = sorted(row_ids) == list(range(1, n + 1))
        print(f"after resuming: {len(row_ids)} records, every row exactly once: {ok}")
    finally:
        shutil.rmtree(work)


def timed_batch(work: Path, truth: np.ndarray, pairs: str = "pairs.csv") -> str:
    """Runs `sdfreg batch` on work/`pairs`, each row's source being its target moved by
    `truth`; the wall time, CPU time, peak RSS and worst errors, as a line (exits on a failed row)."""
    out = work / Path(pairs).with_suffix(".jsonl")
    seconds, cpu, rss = batch_run(work / pairs, out)
    inverse = np.linalg.inv(truth)
    worst = (0.0, 0.0)
    for line in out.read_text().splitlines()[1:]:
        record = json.loads(line)
        if not record["ok"]:
            sys.exit(f"batch.py: row {record['row']} failed: {record['error']}")
        # The transformation maps the source into the target: the truth's inverse.
        errors = pose_errors(np.array(record["transformation"]), inverse)
        worst = (max(worst[0], errors[0]), max(worst[1], errors[1]))
    return (f"{seconds:.2f} s, CPU {cpu:.2f} s ({cpu / seconds:.2f} cores busy), peak RSS {rss:.0f} MiB; "
            f"worst errors {worst[0]:.3f}° / {worst[1] * 1e3:.1f} mm")


def kitti_frames(data: Path) -> list[Path]:
    """The frames of lidar/kitti00_frames in `data` (exits with a message when missing)."""
    frames = sorted((data / "lidar" / "kitti00_frames").glob("*.ply"))
    if not frames:
        sys.exit(f"batch.py: {data}/lidar/kitti00_frames: missing; skipping")
    return frames


def turn_about_z(degrees: float, shift: list[float]) -> np.ndarray:
    """The 4×4 motion that turns by `degrees` about z, then moves by `shift` (metres)."""
    motion = rotation_about(np.array([0.0, 0.0, 1.0]), np.radians(degrees))
    motion[:3, 3] = shift
    return motion


def laz_pairs(data: Path, n: int) -> None:
    frames = kitti_frames(data)
    work = Path(tempfile.mkdtemp(prefix="sdfreg-batch-laz-"))
    try:
        truth = turn_about_z(2.9, [0.3, -0.2, 0.05])
        rows = []
        scans = [sdfreg.read_point_cloud(f) for f in frames]
        for k in range(n):
            tiles = []
            for c in range(18):
                # Each tile another frame, turned its own way, on a 3 × 6 grid about the origin:
                # no two tiles alike, so no shift between tiles fits as well as the truth.
                turned = turn_about_z(37.0 * c + 11.0 * k, [0.0, 0.0, 0.0])[:3, :3]
                place = [200.0 * (c % 6 - 2.5), 200.0 * (c // 6 - 1.0), 0.0]
                tiles.append(scans[(c + k) % len(scans)] @ turned.T + place)
            target = np.concatenate(tiles)
            source = target @ truth[:3, :3].T + truth[:3, 3]
            sdfreg.write_point_cloud(work / f"t{k}.laz", target)
            sdfreg.write_point_cloud(work / f"s{k}.laz", source)
            rows.append(f"s{k}.laz,t{k}.laz\n")
        (work / "pairs.csv").write_text("".join(rows))
        print(f"{n} pairs of {len(target)} points in LAZ ({cpu_flags()}): {timed_batch(work, truth)}")
    finally:
        shutil.rmtree(work)


def many_models(data: Path, n: int) -> None:
    frames = kitti_frames(data)
    work = Path(tempfile.mkdtemp(prefix="sdfreg-batch-models-"))
    try:
        truth = turn_about_z(1.5, [0.2, -0.1, 0.05])
        for j, frame in enumerate(frames):
            scan = sdfreg.read_point_cloud(frame)
            sdfreg.write_point_cloud(work / f"s{j}.ply", scan @ truth[:3, :3].T + truth[:3, 3])
            sdfreg.fit(scan).save(work / f"fitted{j}.sdfm")
        rows = []
        for k in range(n):
            # Each model its own file (a copy of one frame's).
            j = k % len(frames)
            shutil.copyfile(work / f"fitted{j}.sdfm", work / f"m{k}.sdfm")
            rows.append(f"s{j}.ply,m{k}.sdfm\n")
        # Each model's two rows one after the other, or every model's first row, then the second.
        (work / "together.csv").write_text("".join(row * 2 for row in rows))
        (work / "apart.csv").write_text("".join(rows * 2))
        model_mib = (work / "m0.sdfm").stat().st_size / 2**20
        print(f"{2 * n} rows against {n} stored models of {model_mib:.1f} MiB each ({cpu_flags()}):")
        for order in ("together", "apart"):
            print(f"  a model's rows {order}: {timed_batch(work, truth, f'{order}.csv')}")
    finally:
        shutil.rmtree(work)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared/data")
    parser.add_argument("--pairs", type=int, default=64)
    parser.add_argument("--protocol", default="clean")
    parser.add_argument("--stress", type=int, metavar="N")
    parser.add_argument("--models", type=int, metavar="N")
    parser.add_argument("--laz", type=int, metavar="N")
    args = parser.parse_args()
    if not CLI.exists():
        sys.exit(f"batch.py: {CLI} not found: cargo build --release -p sdfreg-cli (or set SDFREG_CLI)")
    if args.stress:
        stress(args.stress)
    elif args.laz:
        laz_pairs(args.data, args.laz)
    elif args.models:
        many_models(args.data, args.models)
    else:
        throughput(args)


if __name__ == "__main__":
    main()

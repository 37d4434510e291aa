"""The GIL is released during the work, concurrent calls are independent, and a forked child
(multiprocessing) can register after its parent did."""

from __future__ import annotations

import multiprocessing
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, paper_pair


def test_python_runs_while_a_registration_runs(pair) -> None:
    source, target, _ = pair
    done = threading.Event()

    def work() -> None:
        sdfreg.register(source, target, threads=1, **QUICK)
        done.set()

    worker = threading.Thread(target=work)
    worker.start()
    # With the GIL held by the call, this loop could not advance until the call returned.
    ticks = 0
    while not done.is_set():
        ticks += 1
        time.sleep(0.002)
    worker.join()
    assert ticks >= 20, ticks


def test_concurrent_calls_give_the_sequential_results() -> None:
    pairs = [paper_pair(s, n=600) for s in (21, 22, 23, 24)]
    sequential = [sdfreg.register(s, t, seed=1, **QUICK).transformation for s, t, _ in pairs]
    with ThreadPoolExecutor(max_workers=4) as pool:
        futures = [pool.submit(sdfreg.register, s, t, seed=1, **QUICK) for s, t, _ in pairs]
        concurrent = [f.result().transformation for f in futures]
    for a, b in zip(sequential, concurrent):
        np.testing.assert_array_equal(a, b)


def register_in_child(conn, source, target) -> None:
    result = sdfreg.register(source, target, seed=2, **QUICK)
    conn.send(result.transformation)
    conn.close()


@pytest.mark.skipif(sys.platform != "linux", reason="fork is the Linux default to test")
def test_forked_child_registers_after_the_parent(pair) -> None:
    source, target, _ = pair
    in_parent = sdfreg.register(source, target, seed=2, **QUICK).transformation
    # Fork while another registration is running on a thread of the parent, too.
    background = threading.Thread(
        target=sdfreg.register, args=(source, target), kwargs=QUICK
    )
    background.start()
    ctx = multiprocessing.get_context("fork")
    parent_end, child_end = ctx.Pipe()
    child = ctx.Process(target=register_in_child, args=(child_end, source, target))
    child.start()
    ok = parent_end.poll(300)
    child.join(10 if ok else 0)
    if child.is_alive():
        child.kill()
    background.join()
    assert ok, "the forked child did not finish registering (deadlock?)"
    np.testing.assert_array_equal(parent_end.recv(), in_parent)
    assert child.exitcode == 0



def read_in_child(conn, path) -> None:
    conn.send(sdfreg.read_point_cloud(path))
    conn.close()


@pytest.mark.skipif(sys.platform != "linux", reason="fork is the Linux default to test")
def test_forked_child_reads_a_laz_file_after_the_parent(tmp_path) -> None:
    # 120,000 points: three LASzip chunks, decoded (and compressed) on several threads.
    rng = np.random.default_rng(7)
    path = tmp_path / "cloud.laz"
    sdfreg.write_point_cloud(path, rng.uniform(-50.0, 50.0, (120_000, 3)))
    in_parent = sdfreg.read_point_cloud(path)
    ctx = multiprocessing.get_context("fork")
    parent_end, child_end = ctx.Pipe()
    child = ctx.Process(target=read_in_child, args=(child_end, path))
    child.start()
    ok = parent_end.poll(120)
    # Received before the child is joined: it sends more than a pipe holds.
    in_child = parent_end.recv() if ok else None
    child.join(10 if ok else 0)
    if child.is_alive():
        child.kill()
    assert ok, "the forked child did not finish reading (deadlock?)"
    np.testing.assert_array_equal(in_child, in_parent)
    assert child.exitcode == 0

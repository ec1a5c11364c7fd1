"""A reader decodes its frames into reused memory (docs/performance.md, "The replay outside its stages").

``LogReader.pool`` holds the buffers of every pass over a log: its chunks (read, decompressed) and its
frames' decoded images (``xyz``, ``rgb``, masks, codes). A buffer goes back to the pool only once the
array handed out and every array made from it are gone, so a frame kept by its caller is never written
over; a later frame or pass reuses the memory of frames that are gone (no fresh pages, no page faults).
Every frame is the same bit for bit as the decoding into fresh arrays gives it.
"""

from __future__ import annotations

import gc
import os
import sys
from pathlib import Path

import numpy as np
import pytest
from log_helpers import decoded_in_full
from subprocess_helpers import run_python

from replay.logs.frame import Frame
from replay.logs.mcap_scan import BufferPool
from replay.logs.reader import LogReader
from replay.synth.log import write_synthetic_log


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    # 360 x 480: a frame's xyz (2.1 MB) and rgb (0.5 MB, below the pool's 1 MB: plain arrays) and its masks
    return write_synthetic_log(tmp_path_factory.mktemp("buffers") / "zn.mcap", kind="zinc_nuts", frames=3, seed=21,
                               size=(360, 480))


def _fresh(path: Path) -> dict[int, np.ndarray]:
    """stamp -> xyz decoded into a fresh array (``np.empty``), message by message."""
    return {s: xyz for s, (xyz, _) in decoded_in_full(path)[0].items()}


def _same(f: Frame, xyz: np.ndarray) -> bool:
    return f.xyz.dtype == xyz.dtype and np.array_equal(f.xyz.view(np.uint32), xyz.view(np.uint32))


def _address(a: np.ndarray) -> int:
    return int(a.__array_interface__["data"][0])


def test_a_pooled_array_goes_back_only_after_every_view_of_it() -> None:
    pool = BufferPool()
    a = pool.array((600, 800, 3), np.float32)
    where = _address(a)
    assert a.flags.writeable and a.flags.c_contiguous and a.shape == (600, 800, 3) and a.dtype == np.float32
    z = a[..., 2]  # a view, as a stage takes one
    r = z.reshape(-1)
    del a, z
    gc.collect()
    assert not pool._free and r.size == 600 * 800  # r, a view of it, still reads it
    del r
    assert len(pool._free) == 1
    b = pool.array((1200, 800), np.float32)  # the same bytes, another shape: the buffer is reused
    assert _address(b) == where and not pool._free
    small = pool.array((10, 10), np.uint8)  # below MIN_BYTES: a plain array
    assert small.shape == (10, 10) and small.base is None


def test_frames_are_the_fresh_decoding_bit_for_bit_on_every_pass(log: Path) -> None:
    reader = LogReader(log)
    want = _fresh(log)
    for _ in range(3):  # the second and third passes decode into the first one's memory
        frames = list(reader.frames())
        assert len(frames) == len(want) == 3
        for f in frames:
            assert _same(f, want[f.stamp_ns]), f.index
        del frames, f


def test_a_later_pass_reuses_the_memory_of_frames_that_are_gone(log: Path) -> None:
    reader = LogReader(log)
    first = {_address(f.xyz) for f in reader.frames()}  # each frame dropped before the next is read
    second = [_address(f.xyz) for f in reader.frames()]
    assert set(second) & first, (first, second)


def test_a_frame_kept_by_its_caller_is_never_written_over(log: Path) -> None:
    reader = LogReader(log)
    want = _fresh(log)
    kept = next(iter(reader.frames()))
    masks = {t: m.copy() for t, m in kept.masks.items()}
    codes = {t: c.copy() for t, c in kept.codes.items()}
    rgb = None if kept.rgb is None else kept.rgb.copy()
    for _ in range(2):
        others = list(reader.frames())
        assert all(not np.shares_memory(kept.xyz, o.xyz) for o in others)
        del others
    assert _same(kept, want[kept.stamp_ns])
    assert all(np.array_equal(kept.masks[t], m) for t, m in masks.items()) and masks
    assert all(np.array_equal(kept.codes[t], c) for t, c in codes.items())
    assert rgb is None or np.array_equal(kept.rgb, rgb)


@pytest.mark.parametrize(("given", "expected"), [(None, "0"), ("500", "500")])
def test_the_command_line_keeps_opencv_threads_from_spinning(given: str | None, expected: str) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("OPENCV_THREAD_POOL")}
    if given is not None:
        env["OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER"] = given
    code = ("import os\nfrom replay.process import OPENCV_NO_SPIN, configure_process\nconfigure_process()\n"
            "print(' '.join(os.environ[n] for n in OPENCV_NO_SPIN))")
    out = run_python(code, env=env, check=True).stdout
    assert out.split() == [expected, "0"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
@pytest.mark.parametrize(("given", "expected"), [(None, "True"), ("4", "False")])
def test_the_command_line_gives_its_threads_one_malloc_arena_unless_the_user_chose(given: str | None,
                                                                                 expected: str) -> None:
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    if given is not None:
        env["MALLOC_ARENA_MAX"] = given
    code = "from replay.process import one_malloc_arena\nprint(one_malloc_arena())"
    out = run_python(code, env=env, check=True).stdout
    assert out.strip() == expected


_GLIBC = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")


@_GLIBC
@pytest.mark.parametrize(("given", "expected"), [
    ({}, "True"), ({"MALLOC_MMAP_THRESHOLD_": "1048576"}, "False"), ({"MALLOC_TRIM_THRESHOLD_": "0"}, "False"),
    ({"GLIBC_TUNABLES": "glibc.malloc.mmap_max=8"}, "False"), ({"GLIBC_TUNABLES": "glibc.rtld.nns=4"}, "True"),
])
def test_the_command_line_keeps_freed_memory_unless_the_user_tunes_malloc(given: dict[str, str],
                                                                          expected: str) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))} | given
    code = "from replay.process import keep_freed_memory\nprint(keep_freed_memory())"
    out = run_python(code, env=env, check=True).stdout
    assert out.strip() == expected


#: a process that allocates, fills and frees a 48 MB array (more than glibc's largest dynamic mmap threshold,
#: as a 1920 x 1200 frame's float64 (H, W, 3) image is) five times and prints the minor page faults of each
_REFAULTS = """
import resource, sys
import numpy as np
if sys.argv[1] == "configured":
    from replay.process import configure_process
    configure_process()
faults = []
for _ in range(5):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.empty(48 << 20, np.uint8)
    a.fill(1)
    del a
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(*faults)
"""


@_GLIBC
def test_memory_a_frame_frees_is_reused_without_faulting_it_in_again() -> None:
    """With the command line's settings the later arrays reuse the first one's pages; by glibc's defaults
    each is mapped afresh (12,288 pages of 4 KB, or 24 huge pages where NumPy asks for them)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}
    got = {}
    for how in ("configured", "default"):
        out = run_python(_REFAULTS, how, env=env, check=True).stdout
        got[how] = [int(v) for v in out.split()]
    first, later = got["configured"][0], got["configured"][1:]
    assert first >= 20 and max(later) <= 2, got  # the first array's pages are faulted in once, then reused
    assert min(got["default"][1:]) >= 20, got  # glibc's defaults: every array faulted in again

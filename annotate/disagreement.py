"""The pixels where two filters disagree, kept by ``zcut compare`` for labelling (docs/compare.md,
``disagreement.npz``), and read back by ``zcut annotate LOG --disagreement DIR``: only those pixels can
change the comparison's verdict, so the page lists only them as review groups.

The file is a NumPy ``.npz`` (no pickled objects) of flat arrays:

- ``logs`` (L,) str, ``log_sha256`` (L,) str, ``log_size`` (L,) int64: the compared logs, in order (``log_sha256``:
  the identity ``zcut compare``'s planning gave each, :func:`replay.logs.identity.log_identity`; in a file
  written before it, the SHA-256 of every byte);
- ``primaries`` (2,) str: the methods of A and B compared;
- ``frame_log`` (N,) int64 (into ``logs``), ``frame_index`` (N,) int64, ``frame_stamp_ns`` (N,) int64,
  ``frame_shape`` (N, 2) int64: every compared frame, disagreement or none;
- ``starts`` (N + 1,) int64, ``pixels`` (K,) uint32, ``who`` (K,) uint8: frame n's disagreeing pixels
  are ``pixels[starts[n]:starts[n + 1]]`` (flat row-major indices) and ``who`` says which side
  removed each alone (:data:`ONLY_A` 1, :data:`ONLY_B` 2).
"""

from __future__ import annotations

import os
import threading
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np

from zcut.errors import ParameterError

if TYPE_CHECKING:
    from replay.logs.frame import Frame

#: The file's name in a comparison's folder.
FILE = "disagreement.npz"
#: ``who`` codes: the pixel was removed by A alone, by B alone.
ONLY_A, ONLY_B = 1, 2
KEYS = ("logs", "log_sha256", "log_size", "primaries", "frame_log", "frame_index", "frame_stamp_ns", "frame_shape",
        "starts", "pixels", "who")


class DisagreementRecorder:
    """Collects the disagreement of a comparison frame by frame, then writes :data:`FILE`.

    Each log's content hash (the one ``zcut compare``'s planning computed, else computed in a thread while
    its frames run: :meth:`log`) lets ``zcut annotate`` tell the log it is given is the one compared.
    """

    def __init__(self, primaries: tuple[str, str] = ("", "")) -> None:
        self.primaries = primaries
        self._logs: list[tuple[str, int]] = []
        self._hashes: list[str] = []
        self._threads: list[threading.Thread] = []
        self._frames: list[tuple[int, int, int, int, int]] = []
        self._pixels: list[np.ndarray] = []
        self._who: list[np.ndarray] = []

    def log(self, path: str | os.PathLike[str], *, sha256: str | None = None) -> None:
        """The frames that follow are of the log at ``path``; ``sha256``: its content hash when the caller
        has it (a study's planning hashed every log), else computed here in a thread."""
        from annotate.store import file_sha256

        p = Path(path)
        k = len(self._logs)
        self._logs.append((p.name, p.stat().st_size))
        self._hashes.append(sha256 or "")
        if sha256 is not None:
            return

        def digest() -> None:
            self._hashes[k] = file_sha256(p)

        t = threading.Thread(target=digest, name="zcut-compare-sha256", daemon=True)
        t.start()
        self._threads.append(t)

    def frame(self, index: int, stamp_ns: int, only_a: np.ndarray, only_b: np.ndarray) -> None:
        """One compared frame: the pixels only A removed and those only B removed."""
        assert self._logs, "log() first"
        h, w = only_a.shape
        pa, pb = np.flatnonzero(only_a), np.flatnonzero(only_b)
        pix = np.concatenate([pa, pb])
        order = np.argsort(pix, kind="stable")
        who = np.concatenate([np.full(pa.size, ONLY_A, np.uint8), np.full(pb.size, ONLY_B, np.uint8)])
        self._frames.append((len(self._logs) - 1, int(index), int(stamp_ns), h, w))
        self._pixels.append(pix[order].astype(np.uint32))
        self._who.append(who[order])

    def write(self, out: IO[bytes]) -> None:
        """Write the file to the open binary file ``out`` (waits for the logs' hashes)."""
        for t in self._threads:
            t.join()
        fr = np.array(self._frames, np.int64).reshape(-1, 5)
        sizes = np.array([p.size for p in self._pixels], np.int64)
        np.savez_compressed(
            out, logs=np.array([n for n, _ in self._logs], str), log_sha256=np.array(self._hashes, str),
            log_size=np.array([s for _, s in self._logs], np.int64), primaries=np.array(self.primaries, str),
            frame_log=fr[:, 0], frame_index=fr[:, 1], frame_stamp_ns=fr[:, 2], frame_shape=fr[:, 3:5],
            starts=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
            pixels=np.concatenate(self._pixels) if self._pixels else np.zeros(0, np.uint32),
            who=np.concatenate(self._who) if self._who else np.zeros(0, np.uint8))


@dataclass(frozen=True, slots=True)
class Disagreement:
    """A comparison's disagreement on one log, by frame stamp.

    Attributes
    ----------
    folder : Path
        The comparison's folder.
    primaries : (str, str)
        The methods of A and B compared.
    frames : dict
        stamp (ns) -> ((H, W), flat pixel indices, who codes) of every compared frame of the log.
    """

    folder: Path
    primaries: tuple[str, str]
    frames: dict[int, tuple[tuple[int, int], np.ndarray, np.ndarray]]

    @property
    def n_pixels(self) -> int:
        return int(sum(p.size for _, p, _ in self.frames.values()))

    def summary(self) -> dict[str, object]:
        """What the page says of the review it is open on (``GET /api/session``'s ``focus``): the
        comparison's folder name, the methods of A and B, the pixels and frames in disagreement."""
        a = sum(int((w == ONLY_A).sum()) for _, _, w in self.frames.values())
        return {"folder": self.folder.name, "a": self.primaries[0], "b": self.primaries[1],
                "pixels": self.n_pixels, "only_a": a, "only_b": self.n_pixels - a,
                "frames": sum(p.size > 0 for _, p, _ in self.frames.values()), "compared": len(self.frames)}

    def focus(self, frame: Frame) -> np.ndarray:
        """(H, W) uint8 of the frame: :data:`ONLY_A`, :data:`ONLY_B` where A and B disagree, 0 elsewhere
        (everywhere on a frame the comparison did not hold)."""
        out = np.zeros(frame.shape, np.uint8)
        got = self.frames.get(int(frame.stamp_ns))
        if got is not None and got[0] == tuple(frame.shape):
            out.ravel()[got[1]] = got[2]
        return out


def load(folder: str | os.PathLike[str], log: str | os.PathLike[str]) -> Disagreement:
    """The disagreement of ``log`` in the comparison folder ``folder`` (``zcut compare -o DIR``).

    Raises
    ------
    ParameterError
        One line: not a folder, not a comparison's folder, a file that does not read, or the
        comparison of other logs.
    """
    from annotate.store import file_sha256
    from replay.logs.identity import log_identity

    d = Path(folder)
    what = f"--disagreement {d}"
    if not d.is_dir():
        raise ParameterError(f"{what}: not a folder (give the -o folder of zcut compare)")
    if not (d / "compare.json").is_file():
        raise ParameterError(f"{what}: not a zcut compare output (no compare.json in it)")
    if not (d / FILE).is_file():
        raise ParameterError(f"{what}: no {FILE} in it (a comparison written before zcut compare kept it: run it again)")
    try:
        with open(d / FILE, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # a broken file is closed too
            arrays = {k: z[k] for k in KEYS}
    except (OSError, ValueError, KeyError, EOFError, TypeError, AttributeError, zipfile.BadZipFile) as e:
        raise ParameterError(f"{what}: {FILE} does not read ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
                             ) from None
    # the log's identity as zcut compare's planning computed it (replay.logs.identity), else (a comparison
    # written before it, a log without an index) the SHA-256 of every byte
    stored = arrays["log_sha256"].tolist()
    digest = log_identity(log)
    mine = [i for i, s in enumerate(stored) if s == digest]
    if not mine:
        digest = file_sha256(log)
        mine = [i for i, s in enumerate(stored) if s == digest]
    if not mine:
        names = ", ".join(str(n) for n in arrays["logs"].tolist()) or "no log"
        raise ParameterError(f"{what}: that comparison is of {names}, not of {Path(log).name} (its content differs)")
    starts, pixels, who = arrays["starts"], arrays["pixels"], arrays["who"]
    frames = {}
    for n in np.flatnonzero(np.isin(arrays["frame_log"], mine)).tolist():
        shape = (int(arrays["frame_shape"][n, 0]), int(arrays["frame_shape"][n, 1]))
        a, b = int(starts[n]), int(starts[n + 1])
        frames[int(arrays["frame_stamp_ns"][n])] = (shape, pixels[a:b].astype(np.int64), who[a:b])
    p = [str(x) for x in arrays["primaries"].tolist()]
    return Disagreement(d, (p[0], p[1]) if len(p) == 2 else ("A", "B"), frames)

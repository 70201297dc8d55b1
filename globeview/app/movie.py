"""Movies of tours: every frame rendered headless with all its tiles loaded, streamed to the
ffmpeg that imageio-ffmpeg's wheel carries, written all-or-nothing.

`write_movie` flies a `globeview.Globe` through a `Tour` (`Tour.frame_times`: the first frame
at the first keyframe, the last at the last one), renders each frame as `Globe.render` does
(every tile of the view loaded first: no half-loaded frame), and pipes the RGB frames to
ffmpeg (H.264 in MP4, yuv420p, or a GIF with a palette made from the whole movie). ffmpeg
writes a temporary file beside the target (`fileio.atomic_outputs`), renamed into place
only when ffmpeg has finished and the data is on disk: a full disk, an ffmpeg failure, a
cancel from the progress callback or Ctrl-C leaves nothing behind. ffmpeg's own messages
are kept and turned into one line (`OutputError`), never shown raw.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from fractions import Fraction
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np

from globeview.errors import GlobeviewError
from globeview.fileio import OutputError, atomic_outputs, check_output_file
from globeview.model.tour import Tour, TourError

if TYPE_CHECKING:
    from globeview.app.globe import Globe

__all__ = ["MOVIE_SUFFIXES", "MovieCancelled", "check_fps", "check_movie_size", "write_movie"]

#: The movie kinds, by file suffix.
MOVIE_SUFFIXES = (".mp4", ".gif")
#: Frame rates a movie may have (frames per second).
FPS_RANGE = (1.0, 240.0)
#: Most frames one movie may have (an hour at 60 fps).
MAX_FRAMES = 216_000
#: H.264's constant rate factor (0 lossless .. 51 worst; 18 looks lossless to most eyes).
MP4_CRF = 18

#: ``progress(done, total)``: called before the first frame (done 0) and after each frame
#: is written; returning False cancels the movie (nothing is written).
Progress = Callable[[int, int], "bool | None"]


class MovieCancelled(GlobeviewError):
    """The progress callback cancelled the movie; nothing was written."""


def check_fps(fps: object) -> float:
    """Frames per second, a finite number in `FPS_RANGE`; ValueError (one line) if not."""
    lo, hi = FPS_RANGE
    if isinstance(fps, bool) or not isinstance(fps, int | float | np.integer | np.floating):
        raise ValueError(f"fps must be a number of frames per second, not {fps!r:.40}")
    if not (math.isfinite(float(fps)) and lo <= float(fps) <= hi):
        raise ValueError(f"fps {float(fps):g} is out of range ({lo:g}..{hi:g} frames a second)")
    return float(fps)


def check_movie_size(size: tuple[int, int], suffix: str) -> tuple[int, int]:
    """An MP4 (H.264, 4:2:0 colour) needs even sides: ValueError (one line) for an odd one."""
    if suffix == ".mp4" and (size[0] % 2 or size[1] % 2):
        raise ValueError(
            f"size {size[0]}x{size[1]}: an MP4 needs an even width and height "
            f"(e.g. {size[0] + size[0] % 2}x{size[1] + size[1] % 2})"
        )
    return size


def write_movie(
    globe: Globe,
    tour: Tour,
    path: str | os.PathLike[str],
    size: tuple[int, int],
    fps: float,
    progress: Progress | None = None,
) -> Path:
    """Render ``tour`` on ``globe`` at ``size`` (width, height pixels) and ``fps`` into
    ``path`` (.mp4 or .gif), all-or-nothing; the globe's camera is put back afterwards.
    Returns the path. One line (`GlobeviewError`) for a bad argument or an output that
    cannot be written, checked before the first frame; `MovieCancelled` when ``progress``
    returned False."""
    out = Path(check_output_file(path, "movie", MOVIE_SUFFIXES))
    suffix = out.suffix.lower()
    try:
        fps = check_fps(fps)
        check_movie_size(size, suffix)
    except ValueError as exc:
        raise GlobeviewError(str(exc)) from None
    times = tour.frame_times(fps) if tour.keyframes else None
    if times is None:
        raise TourError("the tour has no keyframes; nothing written")
    if len(times) > MAX_FRAMES:
        raise GlobeviewError(
            f"{len(times)} frames ({tour.duration:g} s at {fps:g} fps): at most {MAX_FRAMES}"
        )
    before = globe.model.camera  # the very object: put back exactly, not re-made from angles
    try:
        with atomic_outputs([out]) as (tmp,), ffmpeg_pipe(tmp, suffix, size, fps) as pipe:
            _tell(progress, 0, len(times))
            for i, t in enumerate(times, 1):
                globe.fly_to(*tour.pose_at(float(t)))
                pipe.write(globe.render(size)[..., :3])
                _tell(progress, i, len(times))
            pipe.finish()
    finally:
        globe.model.camera = before
        globe.registry.attach(camera=before)
    return out


def _tell(progress: Progress | None, done: int, total: int) -> None:
    if progress is not None and progress(done, total) is False:
        raise MovieCancelled(f"movie cancelled after {done} of {total} frames; nothing written")


@contextlib.contextmanager
def ffmpeg_pipe(path: Path, suffix: str, size: tuple[int, int], fps: float) -> Iterator[FfmpegPipe]:
    """ffmpeg (imageio-ffmpeg's binary) writing ``path`` as ``suffix``'s kind from raw RGB
    frames (`FfmpegPipe.write`); its messages go to a temporary file, read back only to
    explain a failure. Leaving the block without `FfmpegPipe.finish` (an error, a cancel,
    Ctrl-C) kills ffmpeg."""
    import imageio_ffmpeg

    rate = str(Fraction(fps).limit_denominator(1001))
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-loglevel", "error", "-y"]
    cmd += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{size[0]}x{size[1]}"]
    cmd += ["-r", rate, "-i", "-", "-an", *_codec_args(suffix), str(path)]
    with tempfile.TemporaryFile() as log:
        # A session of its own: the terminal's Ctrl-C reaches globeview, which stops ffmpeg.
        proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log,
            start_new_session=True,
        )  # fmt: skip
        try:
            yield FfmpegPipe(proc, log, path, size)
        finally:
            if proc.returncode is None:
                proc.kill()
                proc.wait()
            if proc.stdin is not None:
                with contextlib.suppress(BrokenPipeError):
                    proc.stdin.close()


class FfmpegPipe:
    """A running ffmpeg reading frames on its stdin (made by `ffmpeg_pipe`)."""

    def __init__(
        self, proc: subprocess.Popen[bytes], log: IO[bytes], path: Path, size: tuple[int, int]
    ) -> None:
        self._proc = proc
        self._log = log
        self.path = path
        self.size = size

    def write(self, rgb: np.ndarray) -> None:
        """One frame: (height, width, 3) uint8, row 0 at the top."""
        if rgb.shape != (self.size[1], self.size[0], 3):
            raise ValueError(f"frame of shape {rgb.shape} for a {self.size} movie")
        assert self._proc.stdin is not None
        try:
            self._proc.stdin.write(np.ascontiguousarray(rgb, dtype=np.uint8).tobytes())
        except BrokenPipeError:  # ffmpeg stopped: its message says why
            self._proc.wait()
            raise self._failure() from None

    def finish(self) -> None:
        """Close the input and wait for ffmpeg to write the file's end; raises its failure."""
        assert self._proc.stdin is not None
        with contextlib.suppress(BrokenPipeError):
            self._proc.stdin.close()
        if self._proc.wait() != 0:
            raise self._failure()

    def _failure(self) -> Exception:
        """ffmpeg's failure as an OSError (full disk, permissions: `atomic_outputs` words it
        and names the target) or a one-line `OutputError`."""
        self._log.seek(0)
        text = self._log.read()[-4000:].decode("utf-8", "replace")
        for code in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES):
            if os.strerror(code) in text:
                return OSError(code, os.strerror(code), str(self.path))
        lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
        last = lines[-1][:200] if lines else f"exit status {self._proc.returncode}"
        return OutputError(f"ffmpeg could not write the movie: {last}")


def _codec_args(suffix: str) -> list[str]:
    """ffmpeg's output options for a .mp4 (H.264, yuv420p: every player reads it) or a .gif
    (one palette made from all frames, looping)."""
    if suffix == ".gif":
        palette = "split[a][b];[a]palettegen=stats_mode=full[p];[b][p]paletteuse"
        return ["-filter_complex", palette, "-loop", "0", "-f", "gif"]
    return [
        "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", str(MP4_CRF),
        "-movflags", "+faststart", "-f", "mp4",
    ]  # fmt: skip

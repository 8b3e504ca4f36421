"""Type stubs of the native module `optistim._optistim` (python/src/lib.rs)."""

from __future__ import annotations

import os
from typing import Any, Iterator, Sequence

import numpy as np
import numpy.typing as npt

__version__: str

class Scene:
    """A validated scene: body, Sun, camera and detector, render settings, its own pose."""

    @staticmethod
    def from_toml(path: str | os.PathLike[str]) -> Scene:
        """Reads and validates a scene file (docs/scene.md); its paths are relative to it.
        Raises SceneError."""
    @staticmethod
    def from_dict(scene: dict[str, Any], base_dir: str | os.PathLike[str] | None = None) -> Scene:
        """A scene from a dict with the TOML file's tables and keys; relative paths from
        `base_dir` (default: the working folder). Raises SceneError."""
    @property
    def pose(self) -> Pose:
        """The scene's own pose ([pose] of the file)."""
    @property
    def size(self) -> tuple[int, int]:
        """Image width and height [px]."""
    @property
    def budgeted(self) -> bool:
        """True under fidelity = "budget" (each frame's settings from the planner)."""
    @property
    def toml(self) -> str:
        """The scene's TOML text."""

class Pose:
    """A pose in the body frame: camera position [m], camera -> body quaternion (w, x, y, z),
    Sun position [m], frame id (seeds the noises). Raises PoseError when not finite or when
    the quaternion's norm is off 1 by more than 1e-6."""

    def __init__(
        self,
        camera_position_m: Sequence[float],
        quaternion_wxyz: Sequence[float],
        sun_position_m: Sequence[float],
        frame_id: int = 0,
    ) -> None: ...
    @property
    def camera_position_m(self) -> list[float]: ...
    @property
    def quaternion_wxyz(self) -> list[float]: ...
    @property
    def sun_position_m(self) -> list[float]: ...
    @property
    def frame_id(self) -> int: ...

class Frame:
    """One rendered frame; images are (height, width), row-major from the top-left."""

    @property
    def power(self) -> npt.NDArray[np.float64]:
        """Collected power per pixel [W]: height x width, or bands x height x width for a
        camera of several bands (in `bands` order)."""
    @property
    def signal(self) -> npt.NDArray[np.float64]:
        """Signal per pixel [e-/s], per band like `power`."""
    @property
    def dn(self) -> npt.NDArray[np.uint16]:
        """Saved DN per pixel (noise included): per band, or one raw mosaic for a Bayer
        camera."""
    @property
    def bands(self) -> list[str]:
        """The camera's band names, in the order of the arrays' planes."""
    @property
    def depth(self) -> npt.NDArray[np.float64]:
        """Range to the surface per pixel [m], NaN where empty."""
    @property
    def pose(self) -> Pose: ...
    @property
    def stats(self) -> dict[str, Any]:
        """Phase [deg], quadrangles sampled and kept, covered pixels, timings_ms per stage."""
    @property
    def settings(self) -> dict[str, Any]:
        """Every setting the frame was rendered with (the planner's under a budget)."""
    @property
    def error(self) -> dict[str, Any] | None:
        """Under fidelity = "budget": the chosen rung, the predicted relative errors
        (median, p99 per lit pixel, total), the budget and whether it is met, what the
        planner saw. None with fixed settings."""
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    def encode(self) -> dict[str, bytes]:
        """power.fits, signal.fits, depth.fits and image.png in memory (optistim render's bytes)."""
    def to_fits(self, dir: str | os.PathLike[str]) -> None:
        """Writes the four files into `dir`, each whole or not at all. Raises RenderError."""
    def record(self, index: int, t_s: float = 0.0) -> str:
        """The frame's manifest row (frame.json) as JSON text."""

class Trajectory(Iterator[Frame]):
    """render_trajectory's iterator: one Frame per pose, rendered when asked for."""

    def __iter__(self) -> Trajectory: ...
    def __next__(self) -> Frame: ...
    def __len__(self) -> int: ...
    @property
    def times_s(self) -> list[float]: ...

def render(
    scene: Scene,
    pose: Pose | Sequence[float] | npt.ArrayLike | None = None,
    *,
    frame_id: int | None = None,
    threads: int | None = None,
) -> Frame:
    """Renders one frame (the GIL released). `pose`: a Pose, 7 or 10 numbers (camera [m],
    quaternion w, x, y, z[, Sun [m]]), or None for the scene's own. `threads`: default
    RAYON_NUM_THREADS, else the CPUs this process may use. Raises PoseError, RenderError."""

def render_trajectory(
    scene: Scene,
    poses: npt.ArrayLike | str | os.PathLike[str],
    *,
    threads: int | None = None,
) -> Trajectory:
    """An iterator of Frames over an (N, 7) / (N, 10) array or a pose file (CSV, JSON lines);
    frame ids count from 0. Raises PoseError."""

def render_threads(threads: int | None = None) -> int:
    """The threads render uses for `threads`."""

def load_poses(scene: Scene, poses: npt.ArrayLike | str | os.PathLike[str]) -> npt.NDArray[np.float64]:
    """(N, 11) rows: t [s], camera [m], quaternion w, x, y, z, Sun [m], as written."""

def exposure(
    scene: Scene,
    poses: npt.ArrayLike | str | os.PathLike[str],
    *,
    keep: float = 0.95,
    dnr_db: float | None = None,
    threads: int | None = None,
    out: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """Exposure planning (Sec. 6.3.2, Eqs. 61-62): per frame the bracket [t_lo_s, t_hi_s]
    keeping `keep` of the active pixels above noise and at most 1 - keep saturated; the loss
    on an exposure grid (arrays `exposures_s`, `saturated`, `under_noise`, pooled ones); the
    trajectory's bracket `bracket_s`. With `out`, the CSV files and the chart too."""

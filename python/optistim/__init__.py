"""optistim: physically based, radiometrically consistent images of planets, moons and small
bodies, from Python.

    >>> import optistim
    >>> scene = optistim.Scene.from_toml("config/nrho_bench.toml")
    >>> frame = optistim.render(scene)            # the scene's own pose
    >>> frame.power.shape, frame.power.dtype       # (height, width), float64 [W]
    >>> for frame in optistim.render_trajectory(scene, "nrho_2orbits.csv"): ...

Poses are in the body frame: camera position [m], the camera -> body quaternion scalar first
(w, x, y, z), Sun position [m] (`docs/conventions.md`). Rendering releases the GIL and runs in
a rayon pool of `threads` threads (default `RAYON_NUM_THREADS`, else the CPUs this process may
use). `optistim.dataset` generates datasets along trajectories, on Ray or in one process.
"""

from ._optistim import (
    Frame,
    Pose,
    Scene,
    Trajectory,
    __version__,
    exposure,
    load_poses,
    render,
    render_threads,
    render_trajectory,
)
from .errors import OptistimError, PoseError, RenderError, SceneError

__all__ = [
    "Frame",
    "OptistimError",
    "Pose",
    "PoseError",
    "RenderError",
    "Scene",
    "SceneError",
    "Trajectory",
    "__version__",
    "exposure",
    "load_poses",
    "render",
    "render_threads",
    "render_trajectory",
]

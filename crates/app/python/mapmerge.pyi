"""mapmerge: merges robot maps (pose graphs, occupancy grids, laser sessions, the lifelong atlas).

Poses, scans and grids are numpy arrays; reports are the dicts ``mapmerge ... --json`` prints.
Errors raise ``MapmergeError`` with the message the CLI prints after ``mapmerge: error:``;
those the CLI exits with code 2 for (unreadable or malformed input, bad arguments) raise
``BadInputError``, a subclass of both ``MapmergeError`` and ``ValueError``.

A grid is a ``(height, width)`` float32 array of occupancy probabilities (0.5 where unknown),
row 0 at the bottom (``plt.imshow(grid, origin="lower")``); the dict that holds it gives
``grid_origin_m`` (``(x, y)``, the lower-left corner of cell ``[0, 0]``, m) and
``grid_resolution_m``.
"""

import os
from typing import Any, Literal, Optional, Sequence, Union, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "__version__",
    "Atlas",
    "BadInputError",
    "Graph",
    "MapmergeError",
    "assemble",
    "grid_merge",
    "optimize",
    "read_graph",
    "read_log",
    "run_atlas",
    "slam",
    "write_graph",
]

_Path = Union[str, "os.PathLike[str]"]

class MapmergeError(Exception):
    """A failure the CLI reports as ``mapmerge: error: MESSAGE`` (exit code 1)."""

class BadInputError(MapmergeError, ValueError):
    """Unreadable or malformed input, bad arguments (the CLI's exit code 2)."""

@final
class Graph:
    """A pose graph as read from a g2o or TORO file (2D or 3D), with the file's ids and format.

    Immutable: ``optimize`` and ``with_poses`` return new graphs.
    """

    @property
    def dimension(self) -> Literal[2, 3]:
        """2 (SE(2) poses) or 3 (SE(3) poses)."""
    @property
    def format(self) -> Literal["g2o", "toro"]:
        """The format it was read in (and is written in by default)."""
    @property
    def source(self) -> str:
        """The file it was read from."""
    @property
    def ids(self) -> npt.NDArray[np.uint64]:
        """Vertex ids, ascending: the rows of ``poses``."""
    @property
    def poses(self) -> npt.NDArray[np.float64]:
        """``(N, 3)`` ``[x, y, yaw]`` in 2D, ``(N, 7)`` ``[x, y, z, qx, qy, qz, qw]`` in 3D (m, rad)."""
    @property
    def edges(self) -> npt.NDArray[np.uint64]:
        """``(E, 2)`` ``[from, to]`` vertex ids, in file order (a prior has ``from == to``)."""
    @property
    def num_vertices(self) -> int: ...
    @property
    def num_edges(self) -> int: ...
    def with_poses(self, poses: npt.NDArray[np.float64]) -> "Graph":
        """The same graph with other poses (the shape of ``poses``, rows in ``ids`` order)."""
    def __len__(self) -> int: ...

def read_graph(
    path: _Path, *, bad_information: Literal["reject", "keep-diagonal"] = "reject"
) -> Graph:
    """Reads a g2o or TORO graph file (2D or 3D; ``.xz`` is decompressed).

    ``bad_information="keep-diagonal"`` keeps the diagonal of information matrices that are
    not positive definite instead of refusing the file.
    """

def write_graph(
    path: _Path, graph: Graph, format: Optional[Literal["g2o", "toro"]] = None
) -> None:
    """Writes ``graph`` in ``format`` (default: the format it was read in), with its ids."""

def optimize(
    graph: Union[Graph, _Path],
    robust: Literal["none", "huber", "cauchy", "dcs", "gnc"] = "none",
    init: Literal["auto", "none", "odometry", "global"] = "auto",
    *,
    algorithm: Literal["lm", "gn"] = "lm",
    max_iterations: Optional[int] = None,
    relative_tolerance: Optional[float] = None,
    kernel_width: Optional[float] = None,
    bad_information: Literal["reject", "keep-diagonal"] = "reject",
    output: Optional[_Path] = None,
) -> tuple[Graph, dict[str, Any]]:
    """Initialises and optimises a graph, as ``mapmerge optimize`` does.

    The defaults are the CLI's (``max_iterations`` 100, ``relative_tolerance`` 1e-9).
    Returns the optimised graph (``.poses``) and the report ``mapmerge optimize --json``
    prints: ``initial_chi2``, ``final_chi2``, ``iterations``, ``termination``,
    ``rejected_edges`` (``robust="gnc"``: by index among the file's edge lines), timings,
    ``iteration_log``, ... With ``output``, the result is also written there. A numerical
    failure is a ``RuntimeWarning`` (the graph holds the last good state), as the CLI writes
    the last good state and exits with code 1.
    """

def grid_merge(
    a_yaml: _Path,
    b_yaml: _Path,
    *,
    output: Optional[_Path] = None,
    hypotheses: int = 4,
) -> dict[str, Any]:
    """Merges map ``b`` into map ``a`` (ROS map_server YAML, any resolutions), no guess needed.

    Returns the dict ``mapmerge grid-merge --json`` prints (``accepted``, ``reason``,
    ``transform`` = ``{"x", "y", "yaw"}`` of B's map frame in A's, ``acceptance``, ``sm``,
    ``dm``, ``hypotheses``, ``procedure``, ...) plus the merged grid in A's frame and resolution
    (``grid``, ``grid_origin_m``, ``grid_resolution_m``; ``None`` when not merged). Not merging
    is not an error. With ``output`` (a YAML path) it also writes the merged map and the picture
    there, as the CLI does.
    """

def read_log(
    log_or_bag: _Path, *, scan_topic: Optional[str] = None, odom_topic: Optional[str] = None
) -> dict[str, Any]:
    """Reads a laser session (CARMEN log, plain or xz, or a ROS 2 bag) as arrays, one row per scan.

    Keys: ``stamps`` (N,), ``odometry`` (N, 3) ``[x, y, yaw]`` (NaN where a scan carries no
    pose), ``ranges`` (N, B) float32 (a list of arrays when beam counts differ),
    ``angle_min``, ``angle_increment``, ``range_min``, ``range_max`` (N,),
    ``robot_from_sensor`` (N, 3), ``log``. A bag's topics are found by type;
    ``scan_topic`` / ``odom_topic`` choose when it has several.
    """

def slam(
    log_or_bag: _Path,
    *,
    resolution: float = 0.05,
    scan_topic: Optional[str] = None,
    odom_topic: Optional[str] = None,
) -> dict[str, Any]:
    """2D graph SLAM on a laser session, as ``mapmerge slam`` runs it.

    Returns ``trajectory`` (N, 3) ``[x, y, yaw]`` of every scan, ``stamps`` (N,), the map from
    every scan at its pose (``grid``, ``grid_origin_m``, ``grid_resolution_m``), ``graph`` (a
    ``Graph``) and the figures of ``mapmerge slam --json`` (``scans``, ``seconds``,
    ``ms_per_scan``, ``front_end``, ``graph_vertices``, ``graph_edges``).
    """

def assemble(
    paths: Sequence[_Path],
    *,
    order: Literal["given", "random"] = "given",
    seed: int = 0,
    trajectory: Literal["slam", "odometry"] = "slam",
) -> dict[str, Any]:
    """Assembles segments without initial guesses, in any order (AutoMerge), as ``mapmerge assemble``.

    Each path is a CARMEN log or ROS 2 bag (named by its file stem; its trajectory by SLAM or
    its odometry) or a KITTI-style folder. Returns the fields of ``mapmerge assemble --json``
    (``segments``, ``arrivals``, ``groups`` with their ``segments``, ``loops``,
    ``pairs_associated``, timings), ``loop_edges`` (the lines of ``loops.jsonl``) and per
    segment name ``poses`` (N, 3) in its group's frame and ``stamps`` (N,).
    """

@final
def run_atlas(
    logs: Sequence[Union[str, os.PathLike[str]]],
    output: Union[str, os.PathLike[str]],
    *,
    kidnap_at: Sequence[int] = (),
    store: Optional[Union[str, os.PathLike[str]]] = None,
    keep_versions: int = 10,
    pictures: bool = True,
    scan_topic: Optional[str] = None,
    odom_topic: Optional[str] = None,
) -> dict[str, Any]:
    """A whole ``mapmerge atlas`` run over laser sessions (one log or bag each, in order).

    The epoch ends with a restart between logs and with a kidnap at ``kidnap_at`` (scans
    counted over all logs from 0). Writes ``output``'s ``events.jsonl``, ``atlas/`` and, with
    ``pictures``, ``pictures/``; with ``store``, continues its newest atlas and commits one
    version per session. Returns the fields of ``mapmerge atlas --json`` (no judging).
    """

class Atlas:
    """The lifelong mapping loop (``mapmerge atlas``'s engine, default parameters), scan by scan.

    It tracks, inserts keyframes, closes loops, merges epochs by place recognition (conditional
    first, then full), checks merges and undoes wrong ones. ``end_epoch`` marks a kidnap or a
    restart. Events and merge decisions are the dicts of ``events.jsonl``.
    """

    def __init__(self) -> None: ...
    def add_scan(
        self,
        odometry: Sequence[float],
        ranges: npt.ArrayLike,
        *,
        angle_min: float,
        angle_increment: float,
        range_max: float,
        range_min: float = 0.0,
        robot_from_sensor: Optional[Sequence[float]] = None,
        stamp: Optional[float] = None,
    ) -> dict[str, Any]:
        """Feeds one scan with the robot's odometry pose ``[x, y, yaw]``.

        ``ranges`` are metres per beam at ``angle_min + k * angle_increment`` in the sensor
        frame (``robot_from_sensor`` ``[x, y, yaw]``, default the robot's origin); readings at or
        above ``range_max`` carry no return. Returns ``keyframe`` (the node it became, or
        None), ``anchor`` (the keyframe it hangs on) and ``events``.
        """
    def end_epoch(
        self, reason: Literal["kidnap", "restart", "tracking_failure"] = "kidnap"
    ) -> list[dict[str, Any]]:
        """Ends the epoch; the next scan starts a new one. Returns the events."""
    def finish(self) -> None:
        """Optimises once more if loops wait (after a session's last scan)."""
    @property
    def events(self) -> list[dict[str, Any]]:
        """Every event so far (epochs, keyframes' loops, hypotheses, merges, unmerges)."""
    @property
    def merges(self) -> list[dict[str, Any]]:
        """Every merge decision (``state``: conditional, full, rejected or undone), as it went."""
    @property
    def hypotheses(self) -> dict[str, int]:
        """Counters of the merge and recovery hypotheses."""
    @property
    def scans(self) -> int: ...
    @property
    def travel_m(self) -> float: ...
    @property
    def epoch(self) -> int: ...
    @property
    def robot_pose(self) -> Optional[npt.NDArray[np.float64]]:
        """``[x, y, yaw]`` in the map the robot is in; None before the first scan."""
    @property
    def graph(self) -> Graph:
        """The graph the robot is in (with a conditional merge, its preview)."""
    @property
    def graphs(self) -> list[Graph]:
        """Every graph: the active one, then the inactive maps."""
    def trajectories(self) -> list[dict[str, Any]]:
        """Every map with the scans that hang on it, as ``atlas -o DIR`` writes ``DIR/maps/``:
        ``map``, ``epochs``, and per scan ``scans`` (numbers from 0), ``scan_epochs``,
        ``stamps`` (NaN where none was given) and ``poses`` (``(N, 3)`` in the map's frame)."""

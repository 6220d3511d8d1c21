"""Finding, loading and fetching the EARL data (demonstrations, MuJoCo assets, published curves).

Layout of an EARL data directory (see ``shared/earl/README.md``)::

    demos/<env>/{forward,reverse}.npz     keys observations, actions, rewards, terminals, next_observations
    assets/tabletop/...                   the tabletop MuJoCo model
    assets/metaworld_earl/...             EARL's copies of the Sawyer models
    assets/kitchen/...                    EARL's kitchen models (adept_envs, adept_models, third_party/franka)
    assets/minitaur/...                   EARL's minitaur pen (wall_tile.urdf, original.urdf)
    reference/published_curves.csv.gz     published learning curves (long format)

Search order (first hit wins): an explicit directory (``--data-dir`` / ``HARNESS_DATA_DIR``), the
project-local cache (``HARNESS_CACHE_DIR`` or ``<project>/.cache/earl``, filled by
``harness data fetch``), then ``../shared/earl`` beside the checkout.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import tempfile
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from algorithms.api import DEMO_FIELDS

#: the envs whose demonstrations EARL's repository publishes (what ``harness data fetch`` downloads): a fact of that
#: repository, like the paths below. The env registry is ``harness.envs.ENVS`` (which imports this module for the
#: assets); any registered env's demos are read from ``demos/<env>/`` of the data directory (docs/extending.md).
ENV_NAMES = ("tabletop_manipulation", "sawyer_door", "sawyer_peg")
DIRECTIONS = ("forward", "reverse")
EARL_REPO_URL = "https://raw.githubusercontent.com/architsharma97/earl_benchmark/main"


class DataNotFoundError(RuntimeError):
    """Raised with one line saying where we looked and how to fix it."""


PROJECT_ROOT = Path(__file__).resolve().parent.parent


def cache_dir() -> Path:
    env = os.environ.get("HARNESS_CACHE_DIR")
    return Path(env).expanduser() if env else PROJECT_ROOT / ".cache" / "earl"


def state_dir() -> Path:
    """Where the harness keeps what it measured on this machine (the speed calibration of ``--dry-run``):
    ``HARNESS_STATE_DIR``, else the project cache. Kept apart from the data so that tests (and anyone else) can point
    it elsewhere without losing the data."""
    env = os.environ.get("HARNESS_STATE_DIR")
    return Path(env).expanduser() if env else cache_dir()


def candidate_dirs(explicit: str | os.PathLike | None = None) -> list[tuple[str, Path]]:
    """The places searched, in order, with a label each. An explicit directory (``--data-dir`` or
    ``HARNESS_DATA_DIR``) is the only place searched: a user who names one must get that data or an error."""
    if explicit:
        return [("--data-dir", Path(explicit).expanduser())]
    if os.environ.get("HARNESS_DATA_DIR"):
        return [("HARNESS_DATA_DIR", Path(os.environ["HARNESS_DATA_DIR"]).expanduser())]
    out: list[tuple[str, Path]] = []
    out.append(("cache", cache_dir()))
    out.append(("../shared/earl", PROJECT_ROOT.parent / "shared" / "earl"))
    return out


_explicit_default: str | None = None


def set_data_dir(path: str | os.PathLike | None) -> None:
    """Set the process-wide explicit data directory (the CLI's ``--data-dir``)."""
    global _explicit_default
    _explicit_default = str(path) if path else None


def explicit_data_dir() -> str | None:
    """The data directory the user named (``--data-dir``, else ``HARNESS_DATA_DIR``), or None."""
    return _explicit_default or os.environ.get("HARNESS_DATA_DIR") or None


def find_data_dir(need: str = "demos", explicit: str | os.PathLike | None = None) -> Path:
    """The first candidate directory holding ``need`` (a relative path such as ``demos`` or
    ``assets/tabletop``). Raises :class:`DataNotFoundError` with one line otherwise."""
    explicit = explicit or _explicit_default
    cands = candidate_dirs(explicit)
    for _, d in cands:
        if (d / need).exists():
            return d
    looked = ", ".join(f"{label} ({d})" for label, d in cands)
    if need.startswith("reference"):  # EARL's released evaluations and the RISC paper's curves, one CSV
        raise DataNotFoundError(f"the published learning curves ('{need}') not found; looked in {looked}. They come "
                                "with the project's data set, not something `harness data fetch` downloads: put the "
                                "file in a data directory (HARNESS_DATA_DIR / --data-dir), or use published=none")
    if len(cands) == 1:
        label, d = cands[0]
        what = "does not exist" if not d.exists() else f"has no '{need}'"
        raise DataNotFoundError(f"the EARL data directory given by {label} ({d}) {what}. Fix: point {label} at a "
                                "directory made by `harness data fetch` (demos/, assets/), or unset it")
    raise DataNotFoundError(f"EARL data '{need}' not found; looked in {looked}. Fix: run `harness data fetch` (offline: "
                            "`harness data scripted`), or set HARNESS_DATA_DIR / --data-dir to an EARL data directory.")


def asset_path(*parts: str) -> Path:
    rel = "/".join(("assets",) + parts)
    return find_data_dir(rel) / rel


@dataclass(frozen=True)
class Demos:
    """A set of demonstrations of one env and direction, as flat transition arrays.

    Each trajectory ends at a ``terminals`` row (its only reward-1 transition)."""

    env: str
    direction: str  # "forward" or "reverse" (backward)
    observations: np.ndarray  # (N, obs_dim) float32
    actions: np.ndarray  # (N, act_dim) float32
    rewards: np.ndarray  # (N,) float32
    terminals: np.ndarray  # (N,) bool
    next_observations: np.ndarray  # (N, obs_dim) float32
    source: str = "earl"  # "earl" or "scripted"

    def __len__(self) -> int:
        return len(self.actions)

    def trajectory_slices(self) -> list[slice]:
        from algorithms.api import demo_segments

        starts, _ = demo_segments(self.terminals)
        ends = np.append(starts[1:], len(self))
        return [slice(int(a), int(b)) for a, b in zip(starts, ends)]

    def trajectories(self) -> list[dict[str, np.ndarray]]:
        return [{k: getattr(self, k)[sl] for k in DEMO_FIELDS} for sl in self.trajectory_slices()]


#: ``Demos.source`` of the empty demo sets that an env without demonstrations (``EnvInfo.demos=False``) gets
NO_DEMOS = "none"


def empty_demos(env: str, direction: str, obs_dim: int, act_dim: int) -> Demos:
    """No transitions, in an env's shapes (source :data:`NO_DEMOS`): what :func:`harness.envs.load_env_demos` gives
    for an env without demonstrations."""
    obs = np.zeros((0, obs_dim), dtype=np.float32)
    return Demos(env=env, direction=direction, observations=obs, actions=np.zeros((0, act_dim), dtype=np.float32),
                 rewards=np.zeros(0, dtype=np.float32), terminals=np.zeros(0, dtype=bool), next_observations=obs.copy(),
                 source=NO_DEMOS)


def demos_fingerprint(env: str) -> dict[str, str | None]:
    """Where the demos of ``env`` were read from and a SHA-256 of their two files (recorded in ``run.yaml``)."""
    h = hashlib.sha256()
    paths = [demo_path(env, d) for d in DIRECTIONS]
    for p in paths:
        h.update(p.read_bytes())
    return {"data_dir": str(paths[0].parent.parent.parent.resolve()), "demos_sha256": h.hexdigest()}


def demo_path(env: str, direction: str, data_dir: Path | None = None) -> Path:
    data_dir = data_dir or find_data_dir(f"demos/{env}/{direction}.npz")
    return data_dir / "demos" / env / f"{direction}.npz"


def load_demos(env: str, direction: str = "forward", data_dir: str | os.PathLike | None = None) -> Demos:
    """Load the demonstrations of ``env`` (``direction`` forward or reverse) into a :class:`Demos`: EARL's, or any
    in the same layout (``demos/<env>/<direction>.npz``, e.g. written by ``harness data scripted``)."""
    if not env or env != Path(env).name or env.startswith("."):
        raise ValueError(f"bad env name {env!r}: a registered env's short name")
    if direction not in DIRECTIONS:
        raise ValueError(f"unknown demo direction {direction!r}; known: forward, reverse")
    # an env outside EARL's: `harness data fetch` cannot bring its demos, say what can
    hint = "" if env in ENV_NAMES else (f" ({env!r} is not an EARL env: write its demos with `harness data scripted "
                                        f"env={env}` or into demos/{env}/ of the data directory; docs/extending.md)")
    try:
        root = Path(data_dir) if data_dir else find_data_dir(f"demos/{env}/{direction}.npz")
    except DataNotFoundError as e:
        raise DataNotFoundError(f"{e}{hint}") from None
    path = root / "demos" / env / f"{direction}.npz"
    if not path.exists():
        raise DataNotFoundError(f"demonstrations not found: {path}{hint}")
    with np.load(path) as z:
        missing = [k for k in DEMO_FIELDS if k not in z]
        if missing:
            raise DataNotFoundError(f"{path} lacks keys {missing}")
        arr = {k: z[k] for k in DEMO_FIELDS}
        source = str(z["source"]) if "source" in z else "earl"
    return Demos(
        env=env,
        direction=direction,
        observations=arr["observations"].astype(np.float32),
        actions=arr["actions"].astype(np.float32),
        rewards=arr["rewards"].reshape(-1).astype(np.float32),
        terminals=arr["terminals"].reshape(-1).astype(bool),
        next_observations=arr["next_observations"].astype(np.float32),
        source=source,
    )


def save_demos(path: Path, arrays: dict[str, np.ndarray], source: str) -> None:
    """Write demos in EARL's npz layout, atomically (rewards/terminals as (N, 1))."""
    out = {k: np.asarray(arrays[k]) for k in DEMO_FIELDS}
    out["rewards"] = out["rewards"].reshape(-1, 1).astype(np.float32)
    out["terminals"] = out["terminals"].reshape(-1, 1).astype(bool)
    for k in ("observations", "actions", "next_observations"):
        out[k] = out[k].astype(np.float32)
    atomic_write_bytes(path, _npz_bytes(out, source))


def _npz_bytes(arrays: dict[str, np.ndarray], source: str) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, source=np.array(source), **arrays)
    return buf.getvalue()


#: below this much free space a failed write is called what it most likely is: a full disk
DISK_FULL_BYTES = 64 << 20


def disk_full(path: Path, error: BaseException) -> OSError | None:
    """A one-line :class:`OSError` for a write to ``path`` that failed because its disk is full (ENOSPC, or any error,
    such as torch's "[enforce fail at inline_container.cc] unexpected pos", with less than 64 MiB left), else None."""
    import errno
    import shutil

    if isinstance(error, (KeyboardInterrupt, SystemExit)):
        return None
    try:
        free = shutil.disk_usage(Path(path).parent if not Path(path).is_dir() else path).free
    except OSError:
        free = None
    if getattr(error, "errno", None) == errno.ENOSPC or (free is not None and free < DISK_FULL_BYTES):
        left = f"{free / 2**20:.0f} MiB free" if free is not None else "no space"
        return OSError(errno.ENOSPC, f"the disk of {Path(path).parent} is full ({left}) while writing {Path(path).name}: "
                                     "free space, then run the same command: the runs resume from their last "
                                     "checkpoint")
    return None


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temp file in the same directory and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException as e:
        Path(tmp).unlink(missing_ok=True)
        full = disk_full(path, e)
        if full is not None:
            raise full from None
        raise


# ---------------------------------------------------------------------------------------------
# harness data fetch
# ---------------------------------------------------------------------------------------------


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """EARL's demo pickles hold dicts of numpy arrays; refuse anything else."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
        ("builtins", "dict"),
        ("builtins", "list"),
        ("collections", "OrderedDict"),
    }

    def find_class(self, module, name):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name} from a demo pickle")


def demo_pickle_to_arrays(raw: bytes) -> dict[str, np.ndarray]:
    d = _NumpyOnlyUnpickler(io.BytesIO(raw)).load()
    missing = [k for k in DEMO_FIELDS if k not in d]
    if missing:
        raise ValueError(f"demo pickle lacks keys {missing}")
    return {k: np.asarray(d[k]) for k in DEMO_FIELDS}


def remote_demo_path(env: str, direction: str) -> str:
    return f"earl_benchmark/demonstrations/{env}/{direction}/demo_data.pkl"


TABLETOP_ASSET_FILES = (
    "tabletop_manipulation.xml", "coffee_mug.stl", "magnet.stl",
    "darkwood.png", "light_wood_v3.png", "marble.png",
)


#: EARL's copies of the Meta-World Sawyer models the door and peg tasks load, with what they include (paths under the
#: repository's ``earl_benchmark/envs/metaworld_assets/``; fetched to ``assets/metaworld_earl/``)
SAWYER_ASSET_FILES = (
    "sawyer_xyz/sawyer_door_pull.xml", "sawyer_xyz/sawyer_peg_insertion_side.xml", "scene/basic_scene.xml",
    *(f"objects/assets/{n}.xml" for n in ("doorlockB", "doorlock_dependencies", "peg_block", "peg_block_dependencies",
                                          "peg_insert_dependencies", "xyz_base", "xyz_base_dependencies")),
    *(f"objects/meshes/doorlock/{n}.stl" for n in ("door", "door_handle", "handle_base", "lock", "lock_base", "safe")),
    "objects/meshes/peg_block/block_inner.stl", "objects/meshes/peg_block/block_outer.stl",
    "objects/meshes/table/tablebody.stl", "objects/meshes/table/tabletop.stl",
    *(f"objects/meshes/xyz_base/{n}.stl" for n in ("base", "eGripperBase", "head", "l0", "l1", "l2", "l3", "l4", "l5",
                                                   "l6", "pedestal")),
    *(f"textures/{n}.png" for n in ("floor2", "metal", "metal1", "metal2", "wood1", "wood2")),
)


#: EARL's kitchen models as its repository holds them (under ``earl_benchmark/envs/kitchen_assets/``; fetched to
#: ``assets/kitchen/``): the scene EARL loads, the kitchen objects, the Franka arm, meshes, textures, licences
KITCHEN_ASSET_FILES = (
    "adept_envs/adept_envs/franka/assets/franka_kitchen_jntpos_act_ab.xml",
    "adept_envs/adept_envs/franka/robot/franka_config.xml",
    "adept_models/LICENSE", "adept_models/README.public.md", "adept_models/scenes/basic_scene.xml",
    "adept_models/scenes/textures/white_marble_tile.png", "adept_models/scenes/textures/white_marble_tile2.png",
    *(f"adept_models/kitchen/{n}.xml" for n in ("counters", "hingecabinet", "kettle", "kitchen", "microwave", "oven",
                                                "slidecabinet")),
    *(f"adept_models/kitchen/assets/{n}_{part}.xml" for n in ("backwall", "counters", "hingecabinet", "kettle",
                                                                "microwave", "oven", "slidecabinet")
      for part in ("asset", "chain")),
    *(f"adept_models/kitchen/meshes/{n}.stl" for n in (
        "burnerplate", "burnerplate_mesh", "cabinetbase", "cabinetdrawer", "cabinethandle", "countertop", "faucet",
        "handle2", "hingecabinet", "hingedoor", "hingehandle", "hood", "kettle", "kettlehandle", "knob", "lightswitch",
        "lightswitchbase", "micro", "microbutton", "microdoor", "microefeet", "microfeet", "microhandle", "microwindow",
        "oven", "ovenhandle", "oventop", "ovenwindow", "slidecabinet", "slidedoor", "stoverim", "tile", "wall")),
    *(f"adept_models/kitchen/textures/{n}.png" for n in ("marble1", "metal1", "tile1", "wood1")),
    "third_party/franka/LICENSE",
    *(f"third_party/franka/assets/{n}.xml" for n in ("actuator0", "actuator1", "assets", "basic_scene", "chain0",
                                                     "chain0_overlay", "chain1", "teleop_actuator")),
    *(f"third_party/franka/meshes/{kind}/{n}.stl" for kind in ("collision", "visual")
      for n in ("finger", "hand", *(f"link{i}" for i in range(8)))),
)

#: EARL's minitaur pen (under ``earl_benchmark/envs/minitaur_assets/``; fetched to ``assets/minitaur/``); the robot
#: itself comes with pybullet (``pybullet_data``)
MINITAUR_ASSET_FILES = ("wall_tile.urdf", "original.urdf")


def _download(url: str, timeout: float = 60.0) -> bytes:
    """The bytes at ``url``; a network failure is one line that says how to go on without the network."""
    req = urllib.request.Request(url, headers={"User-Agent": "earl-harness"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:  # noqa: S310 (http(s) URL built by us)
            return r.read()
    except (OSError, ValueError) as e:  # URLError, HTTPError, timeouts, refused connections, a malformed URL
        reason = getattr(e, "reason", None) or e
        raise DataNotFoundError(
            f"cannot download {url} ({' '.join(str(reason).split())}). Without network: `harness data scripted` writes "
            "demonstrations from the scripted experts, or point --data-dir / HARNESS_DATA_DIR at a copy of EARL's data"
        ) from None


def fetch(
    dest: Path | None = None,
    base_url: str = EARL_REPO_URL,
    envs: tuple[str, ...] = ENV_NAMES,
    assets: bool = True,
    log=print,
) -> Path:
    """Download EARL's demonstration pickles (and the tabletop, Sawyer, kitchen and minitaur model files) into ``dest``
    (the cache),
    converting each pickle to the ``demos/<env>/<direction>.npz`` layout. Files are written
    atomically; an interrupted fetch leaves no half file and can simply be re-run."""
    dest = Path(dest) if dest else cache_dir()
    base_url = base_url.rstrip("/")
    for env in envs:
        for direction in DIRECTIONS:
            target = dest / "demos" / env / f"{direction}.npz"
            url = f"{base_url}/{remote_demo_path(env, direction)}"
            log(f"fetch {url}")
            arrays = demo_pickle_to_arrays(_download(url))
            save_demos(target, arrays, source="earl")
            log(f"  -> {target} ({len(arrays['actions'])} transitions)")
    if assets:
        files = [(f"tabletop_assets/{n}", f"tabletop/{n}") for n in TABLETOP_ASSET_FILES]
        files += [(f"metaworld_assets/{n}", f"metaworld_earl/{n}") for n in SAWYER_ASSET_FILES]
        files += [(f"kitchen_assets/{n}", f"kitchen/{n}") for n in KITCHEN_ASSET_FILES]
        files += [(f"minitaur_assets/{n}", f"minitaur/{n}") for n in MINITAUR_ASSET_FILES]
        for remote, local in files:
            url = f"{base_url}/earl_benchmark/envs/{remote}"
            log(f"fetch {url}")
            atomic_write_bytes(dest / "assets" / local, _download(url))
    return dest


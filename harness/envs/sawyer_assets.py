"""EARL's Sawyer model files, rebuilt offline from the copies inside the ``metaworld`` package.

EARL's ``earl_benchmark/envs/metaworld_assets`` are Meta-World's model files with Windows line endings and five
edits: the door hinge's range (``-1.4 0``, Meta-World 3: ``-2 0``) and a light door (``density="50"`` on its geoms) in
``objects/assets/doorlockB.xml``, and two cameras (``clearview``, ``doorview`` instead of ``corner4``) and the
``gripperPOV`` camera's position in ``objects/assets/xyz_base.xml``. Every other file (meshes, textures, the scene and
the task XMLs) is Meta-World 3's byte for byte, or with CRLF line ends. :func:`write_sawyer_assets` makes those edits
and checks every file against the SHA-256 of EARL's copy, so the result is EARL's files exactly (or an error naming
the file that no longer matches, e.g. after a Meta-World release changed it). ``harness data scripted`` calls it, so a
machine without network gets the door and peg models too (docs/earl_env_comparison.md compares the two models).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from harness.data import SAWYER_ASSET_FILES, DataNotFoundError, atomic_write_bytes

#: SHA-256 (first 16 hex digits) of EARL's copy of each file (earl_benchmark HEAD b05b000)
EARL_SHA256 = {
    "sawyer_xyz/sawyer_door_pull.xml": "f14cdb95f214dc13",
    "sawyer_xyz/sawyer_peg_insertion_side.xml": "a001c569cf11268d",
    "scene/basic_scene.xml": "fc1a8e0c391fbf55",
    "objects/assets/doorlockB.xml": "5c27c97b887a03b1",
    "objects/assets/doorlock_dependencies.xml": "a57ead225b7821be",
    "objects/assets/peg_block.xml": "e6e889d74abeb648",
    "objects/assets/peg_block_dependencies.xml": "96eda23c0560a265",
    "objects/assets/peg_insert_dependencies.xml": "c606a797c06d1e76",
    "objects/assets/xyz_base.xml": "e93a0a90f9003021",
    "objects/assets/xyz_base_dependencies.xml": "a96dbe04c55483ce",
    "objects/meshes/doorlock/door.stl": "95aa50bf44494e74",
    "objects/meshes/doorlock/door_handle.stl": "10a9f30f6f2a0fd1",
    "objects/meshes/doorlock/handle_base.stl": "6f5e1b5b40e0bddf",
    "objects/meshes/doorlock/lock.stl": "596b7feac1c71587",
    "objects/meshes/doorlock/lock_base.stl": "1a9449227bc3aca4",
    "objects/meshes/doorlock/safe.stl": "5f3de085684fe5d8",
    "objects/meshes/peg_block/block_inner.stl": "be68ce180d11630a",
    "objects/meshes/peg_block/block_outer.stl": "748b9e197e652191",
    "objects/meshes/table/tablebody.stl": "fd29fb25de28b6c1",
    "objects/meshes/table/tabletop.stl": "b32a6fdf003e834c",
    "objects/meshes/xyz_base/base.stl": "97b3997a278b7d7b",
    "objects/meshes/xyz_base/eGripperBase.stl": "3112ecc88a650b57",
    "objects/meshes/xyz_base/head.stl": "e2d5dd7e79884178",
    "objects/meshes/xyz_base/l0.stl": "6f4a7f56bcf4cbfb",
    "objects/meshes/xyz_base/l1.stl": "f6d8ba089c3da8a4",
    "objects/meshes/xyz_base/l2.stl": "4a0d2ccf5668f737",
    "objects/meshes/xyz_base/l3.stl": "9faa1f689135fcda",
    "objects/meshes/xyz_base/l4.stl": "a9f7032958ae8fee",
    "objects/meshes/xyz_base/l5.stl": "5078849cf3e1ae77",
    "objects/meshes/xyz_base/l6.stl": "e55c25b435b2e038",
    "objects/meshes/xyz_base/pedestal.stl": "eee21a0809f502db",
    "textures/floor2.png": "cba4a03701e18f2e",
    "textures/metal.png": "93784216a66b52be",
    "textures/metal1.png": "0d25fa8affbb0f57",
    "textures/metal2.png": "70bf8f1c02841b80",
    "textures/wood1.png": "a39fbea7e52f7988",
    "textures/wood2.png": "3cf37d37eee85a14",
}

_DOOR = '          <geom class="dl_col" euler="{}" pos="{}" size="{}" type="cylinder"'
#: EARL's edits of Meta-World's text (after the line ends are made CRLF): (Meta-World 3's text, EARL's text)
EDITS: dict[str, tuple[tuple[str, str], ...]] = {
    "objects/assets/doorlockB.xml": (
        ('range="-2 0"/>', 'range="-1.4 0"/>'),
        ('mesh="door" pos="0.185 0 0"/>', 'mesh="door" density="50" pos="0.185 0 0"/>'),
        ('mesh="door_handle" pos="0.325 -0.062 0"/>', 'mesh="door_handle" pos="0.325 -0.062 0" density="50" />'),
        ('mesh="handle_base" pos="0.325 -0.006 0"/>', 'mesh="handle_base" pos="0.325 -0.006 0" density="50" />'),
        ('size="0.013 .045" type="cylinder"/>', 'size="0.013 .045" type="cylinder" density="50"/>'),
        *((_DOOR.format(e, p, s) + "/>", _DOOR.format(e, p, s) + ' density="50"/>')
          for e, p, s in (("1.57 0 0", "0.325 -0.006 0", "0.028 0.012"), ("1.57 0 0", "0.325 -0.065 0", "0.013 0.047"),
                          ("0 1.57 0", "0.381 -0.12 0", "0.019 0.075"), ("0 1.57 0", "0.395 -0.12 0", "0.023 0.054"))),
        ('size="0.18 0.01 0.123" type="box" />', 'size="0.18 0.01 0.123" type="box" density="50"/>'),
    ),
    "objects/assets/xyz_base.xml": (
        ('      <camera name="corner4" fovy="60" mode="fixed" pos="0.75 0.075 0.7" euler="3.9 2.3 0.6"/>\r\n',
         ('      <camera name="clearview" fovy="60" mode="fixed" pos="1.2 0.3 0.8" euler="3.6 2.3 4"/>\r\n'
          '      <camera name="doorview" fovy="45" mode="fixed" pos="0.8 0.3 0.8" euler="3.6 2.3 4"/>\r\n\r\n')),
        ('<camera name="gripperPOV" mode="track" pos="0.04 -0.06 0"', '<camera name="gripperPOV" mode="track" pos="0 -0.1 0"'),
    ),
}


def _sha(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


def earl_file(rel: str, metaworld_assets: Path) -> bytes:
    """EARL's copy of ``rel`` made from Meta-World's ``metaworld_assets/rel``; checked against EARL's SHA-256."""
    src = metaworld_assets / rel
    if not src.is_file():
        raise DataNotFoundError(f"Meta-World's model file {src} is missing: cannot rebuild EARL's {rel}")
    data = src.read_bytes()
    if _sha(data) != EARL_SHA256[rel] and rel.endswith(".xml"):
        text = data.decode().replace("\r\n", "\n").replace("\n", "\r\n")
        for old, new in EDITS.get(rel, ()):
            text = text.replace(old, new)  # the door's cylinder line appears twice, both edited
        data = text.encode()
    if _sha(data) != EARL_SHA256[rel]:
        raise DataNotFoundError(f"{src} does not rebuild EARL's {rel} (SHA-256 {_sha(data)}, EARL's "
                                f"{EARL_SHA256[rel]}): this Meta-World release changed it; use `harness data fetch`")
    return data


def write_sawyer_assets(dest: Path, log=print) -> Path:
    """EARL's Sawyer model files into ``dest/assets/metaworld_earl`` from the installed Meta-World's; returns that
    directory. Every file is checked before any is written."""
    from importlib.metadata import version

    import metaworld

    mw = Path(metaworld.__file__).resolve().parent / "assets"
    files = {rel: earl_file(rel, mw) for rel in SAWYER_ASSET_FILES}
    out = Path(dest) / "assets" / "metaworld_earl"
    for rel, data in files.items():
        atomic_write_bytes(out / rel, data)
    log(f"EARL's Sawyer models ({len(files)} files, each checked against EARL's SHA-256) written to {out}, "
        f"rebuilt from metaworld {version('metaworld')}")
    return out

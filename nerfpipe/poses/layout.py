"""Recognise a capture folder's layout: which files are its photos, and which files hold its poses.

Both ingest (which photos to read) and sfm (which pose files to import) call ``detect_layout``, so they
always agree. Layouts, in the order they are tried:

- ``transforms``: NeRF / instant-ngp / nerfstudio ``transforms.json`` or ``transforms_{train,val,test}.json``;
  the photos are the frames they name (the splits come from the file names).
- ``colmap``: a COLMAP sparse model (``sparse/0``, ``sparse`` or the folder itself; ``.bin`` or ``.txt``)
  with the photos in ``images/``.
- ``llff``: ``poses_bounds.npy`` with the photos in ``images/`` (rows follow the sorted image names).
- ``middlebury``: a ``*_par.txt`` calibration file naming the photos beside it.
- ``folder``: just photos, in the folder or in its ``images/`` subfolder.
- ``video``: one video file (MP4, MOV, ...), passed itself or alone in its folder; ingest takes its frames.

Every image path a pose file names must resolve inside the capture folder; ``../`` escapes, absolute
paths and links that lead out of it are refused.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Literal

from nerfpipe.pipeline.errors import InputError

LayoutKind = Literal["transforms", "colmap", "llff", "middlebury", "folder", "video"]
from nerfpipe.artifacts import PHOTO_SUBFOLDER

TRANSFORMS_FILES = ("transforms.json", "transforms_train.json", "transforms_val.json", "transforms_test.json")
COLMAP_MODEL_DIRS = ("sparse/0", "sparse", ".")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG", ".tif", ".tiff", ".exr")


@dataclass(frozen=True)
class CaptureLayout:
    kind: LayoutKind
    capture: Path
    photos: list[Path]  # absolute paths of the photos to ingest, sorted
    pose_files: list[Path] = field(default_factory=list)  # files an importer reads
    splits: dict[str, str] = field(default_factory=dict)  # photo relpath (to capture) -> "train" / "val" / "test"


def resolve_inside(capture: Path, name: str, pose_file: Path, suffixes: tuple[str, ...] = ()) -> Path:
    """The photo a pose file names, as an absolute path that must lie inside ``capture``.

    Absolute paths, ``..`` escapes and symbolic links leading out of the folder raise ``InputError``, as
    does a name that resolves to no file (``suffixes`` are tried for extension-less NeRF paths).
    """
    if PurePosixPath(name).is_absolute() or PureWindowsPath(name).is_absolute():
        raise InputError(pose_file, f"names the image {name!r} by an absolute path",
                         "pose files may only name images inside the capture folder, by relative paths")
    root = capture.resolve()
    candidates = [capture / name] + [capture / (name + s) for s in suffixes]
    for candidate in candidates:
        resolved = candidate.resolve()
        if not resolved.is_relative_to(root):
            raise InputError(pose_file, f"names the image {name!r}, which lies outside the capture folder",
                             "pose files may only name images inside the capture folder")
        if resolved.is_file():
            return candidate
    raise InputError(pose_file, f"names the image {name!r}, which does not exist in {capture}",
                     "copy the missing image in, or remove its entry from the pose file")


POSE_FILE_NAMES = {
    "transforms": "transforms.json or transforms_{train,val,test}.json",
    "colmap": "COLMAP model (cameras.bin and images.bin, or .txt, in sparse/0, sparse or the folder itself)",
    "llff": "poses_bounds.npy",
    "middlebury": "*_par.txt calibration file",
}
COLMAP_MODEL_FILES = ("cameras", "images", "points3D")


def detect_layout(capture: Path, kind: str | None = None) -> CaptureLayout:
    """The capture's layout: the first that matches, or exactly ``kind`` when one is asked for."""
    detectors = {"transforms": _transforms, "colmap": _colmap, "llff": _llff, "middlebury": _middlebury}
    if kind is not None and kind != "folder":
        layout = detectors[kind](capture)
        if layout is None and kind == "colmap":
            check_colmap_model(capture, "or use --set sfm.poses=sfm to compute the poses")
        if layout is None:
            raise InputError(capture, f"has no {POSE_FILE_NAMES[kind]} to import poses from",
                             "drop the --set sfm.poses override to detect the poses, or use sfm.poses=sfm")
        return layout
    from nerfpipe.imaging.video import VIDEO_EXTENSIONS

    if capture.exists() and not capture.is_file() and not capture.is_dir():
        raise InputError(capture, "is a device or special file, not a capture folder or a video",
                         "pass the folder of photos, or a video")
    if capture.is_file():
        if capture.suffix.lower() in VIDEO_EXTENSIONS:
            return CaptureLayout("video", capture.parent, [capture])
        raise InputError(capture, "is a file, not a capture folder or a video",
                         f"pass the folder of photos, or a video ({', '.join(sorted(VIDEO_EXTENSIONS))})")
    for detect in detectors.values():
        layout = detect(capture)
        if layout is not None:
            return layout
    photos = discover_photos(capture)
    videos = [p for p in photos if p.suffix.lower() in VIDEO_EXTENSIONS]
    if videos and len(videos) == len(photos):
        if len(videos) > 1:
            raise InputError(capture, f"holds {len(videos)} videos ({', '.join(v.name for v in videos[:3])})",
                             "pass one of them: nerfpipe run FOLDER/VIDEO")
        return CaptureLayout("video", capture, videos)
    return CaptureLayout("folder", capture, photos)


def discover_photos(folder: Path) -> list[Path]:
    """Photo-like files of a plain capture folder, sorted; raises ``InputError`` when there are none.

    Files directly in ``folder`` count; when it holds none, ``folder/images`` is used. Known side-car
    files (poses, notes, XMP) are ignored; any other file is returned, so that ingest names it and says
    what to do instead of silently dropping a photo.
    """
    from nerfpipe.imaging import SIDECAR_EXTENSIONS

    def candidates(where: Path) -> tuple[list[Path], list[Path]]:
        files = sorted(p for p in where.iterdir() if p.is_file() and not p.name.startswith("."))
        return files, [p for p in files if p.suffix.lower() not in SIDECAR_EXTENSIONS]

    files, photos = candidates(folder)
    if not photos and (folder / PHOTO_SUBFOLDER).is_dir():
        files, photos = candidates(folder / PHOTO_SUBFOLDER)
    if photos:
        return photos
    if not files:
        raise InputError(folder, "the capture folder is empty", "put the photos (JPEG, PNG, TIFF or camera RAW) in it")
    shown = ", ".join(p.name for p in files[:3]) + (", ..." if len(files) > 3 else "")
    raise InputError(folder, f"no photos found among its {len(files)} files ({shown})",
                     "nerfpipe reads JPEG, PNG, TIFF and camera RAW files")


def _read_json(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as err:
        raise InputError(path, f"is not valid JSON ({err})", "fix or remove the pose file") from None
    except RecursionError:
        raise InputError(path, "nests its JSON too deeply to be a pose file", "fix or remove the pose file") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise InputError(path, "has no \"frames\" list", "a transforms.json needs a frames list with file_path entries")
    return doc


def _transforms(capture: Path) -> CaptureLayout | None:
    pose_files = [capture / n for n in TRANSFORMS_FILES if (capture / n).is_file()]
    if not pose_files:
        return None
    photos: dict[Path, str] = {}
    for pose_file in pose_files:
        split = pose_file.stem.partition("_")[2] or "train"
        for i, frame in enumerate(_read_json(pose_file)["frames"]):
            name = frame.get("file_path") if isinstance(frame, dict) else None
            if not isinstance(name, str) or not name:
                raise InputError(pose_file, f"frame {i} has no file_path", "every frame needs the path of its image")
            photos.setdefault(resolve_inside(capture, name, pose_file, IMAGE_SUFFIXES), split)
    if not photos:
        raise InputError(pose_files[0] if len(pose_files) == 1 else capture,
                         f"{'has' if len(pose_files) == 1 else 'have'} an empty frames list: no photo to reconstruct",
                         "list each photo under \"frames\" with its file_path and transform_matrix, or remove the "
                         "file to let SfM compute the poses")
    splits = {p.relative_to(capture).as_posix(): s for p, s in photos.items()}
    return CaptureLayout("transforms", capture, sorted(photos), pose_files, splits)


def colmap_model_dir(capture: Path) -> Path | None:
    for sub in COLMAP_MODEL_DIRS:
        folder = capture / sub
        for ext in (".bin", ".txt"):
            if all((folder / f"{n}{ext}").is_file() for n in ("cameras", "images")):
                return folder
    return None


def check_colmap_model(capture: Path, alternative: str) -> None:
    """Raise ``InputError`` naming the missing file when the capture holds part of a COLMAP model: some of
    cameras, images and points3D (.bin or .txt) in a model folder, but not both cameras and images."""
    for sub in COLMAP_MODEL_DIRS:
        folder = capture / sub
        for ext in (".bin", ".txt"):
            present = [f"{n}{ext}" for n in COLMAP_MODEL_FILES if (folder / f"{n}{ext}").is_file()]
            missing = [f"{n}{ext}" for n in COLMAP_MODEL_FILES[:2] if not (folder / f"{n}{ext}").is_file()]
            if present and missing:
                raise InputError(folder / missing[0], f"is missing: the COLMAP model in {folder} has "
                                 f"{' and '.join(present)} but no {' or '.join(missing)}",
                                 f"copy it in from COLMAP's sparse output, {alternative}")


def _colmap(capture: Path) -> CaptureLayout | None:
    model = colmap_model_dir(capture)
    if model is None:
        return None
    if not (capture / PHOTO_SUBFOLDER).is_dir():
        raise InputError(capture, f"has a COLMAP model in {model.relative_to(capture)} but no images/ folder",
                         "put the photos the model was made from in images/")
    pose_files = sorted(p for p in model.iterdir() if p.is_file() and p.stem in ("cameras", "images", "points3D"))
    return CaptureLayout("colmap", capture, discover_photos(capture / PHOTO_SUBFOLDER), pose_files)


def _llff(capture: Path) -> CaptureLayout | None:
    pose_file = capture / "poses_bounds.npy"
    if not pose_file.is_file():
        return None
    if not (capture / PHOTO_SUBFOLDER).is_dir():
        raise InputError(capture, "has poses_bounds.npy but no images/ folder", "put the photos in images/")
    return CaptureLayout("llff", capture, discover_photos(capture / PHOTO_SUBFOLDER), [pose_file])


def _middlebury(capture: Path) -> CaptureLayout | None:
    pose_files = sorted(capture.glob("*_par.txt"))
    if not pose_files:
        return None
    photos = []
    for pose_file in pose_files:
        for line in pose_file.read_text(encoding="utf-8", errors="replace").splitlines()[1:]:
            if line.strip():
                photos.append(resolve_inside(capture, line.split()[0], pose_file))
    return CaptureLayout("middlebury", capture, sorted(set(photos)), pose_files)

"""The NeRF a scene calls for: its ray space, fields, occupancy grid and background, and its training schedule.

Each builder takes the scene decisions (``nerfpipe.artifacts.SceneDecisions``) and the train parameters it
reads, and returns what it built with the sentence that explains the choice (None when there is nothing to
say); ``build_model`` puts them together. The one place that chooses parts: nothing else compares a
field's, sampler's or ray space's kind.

``params`` is any object with the attributes of ``TrainParams`` (``nerfpipe.stages.train``); the ones read
here are listed in ``nerfpipe.nerf.config.TrainSettings``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from nerfpipe.artifacts import Bounds, SceneDecisions
from nerfpipe.geometry.cameras import CameraSet, mean_camera
from nerfpipe.geometry.hull import Silhouettes, hull_box
from nerfpipe.geometry.normalize import robust_box
from nerfpipe.nerf.config import TrainSettings
from nerfpipe.nerf.fields.configs import FieldConfig, MlpConfig
from nerfpipe.nerf.model import RadianceModel, build
from nerfpipe.nerf.spaces.ray_space import BoxSpace, ContractedSpace, NdcSpace, RaySpace
from nerfpipe.nerf.samplers.configs import HierarchicalConfig, SamplerConfig
from nerfpipe.nerf.spec import ModelSpec

CAMERA_MARGIN = 0.05  # the box around the scene and its cameras grows by this share of its size a side
HULL_RESOLUTION = 64  # cells a side of the visual hull that bounds the scene box
POSE_ERROR_PX = 2.0  # mean reprojection error of the sparse points above which camera poses are refined by default
NDC_NEAR_FACTOR = 0.75  # the NDC near plane at 0.75 x the nearest bound, as LLFF's bd_factor places it

Box = tuple[tuple[float, ...], tuple[float, ...]]


def contracts(params: TrainSettings, scene: SceneDecisions) -> bool:
    """Whether space beyond the scene box is contracted (mip-NeRF 360): by default for unbounded scenes, and
    for inward 360 ones whose background is part of the scene (no backdrop colour, no alpha), since a box
    would cut off the floor and walls the photos show and train them as density inside it."""
    if params.space.contract != "auto":
        return params.space.contract == "on"
    layout = scene.layout.value
    return layout == "unbounded360" or (layout == "inward360" and scene.background.value == "none")


def density_noise(params: TrainSettings, layout: str) -> float:
    """The authors regularize real forward-facing scenes with noise of std 1 on the raw density; not synthetic
    ones. The MLP's raw density only: the grid field has no such regularizer."""
    if params.optim.density_noise != "auto":
        return float(params.optim.density_noise)
    return 1.0 if layout == "forward" and isinstance(params.field, MlpConfig) else 0.0


def lindisp(sampler: SamplerConfig, layout: str) -> bool:
    """Sample linearly in disparity: by default for unbounded scenes, whose far bound is far away."""
    choice = getattr(sampler, "lindisp", "auto")  # a sampler without the setting: the scene's default
    return layout == "unbounded360" if choice == "auto" else choice == "on"


def build_ray_space(params: TrainSettings, scene: SceneDecisions, world: CameraSet, bounds: Bounds) -> tuple[RaySpace, str]:
    """NDC rays of the mean camera for forward-facing captures (Section 6.1's real scenes), world rays in
    contracted space for scenes that reach beyond their box (``contracts``), rays clipped to the scene box
    for inward 360° ones with a backdrop, plain world rays otherwise."""
    layout = scene.layout.value
    if contracts(params, scene):
        why = ("unbounded 360" if layout == "unbounded360" else
               f"{layout.replace('inward360', 'inward 360')} with the background part of the scene")
        box, kept = scene_box(bounds), "the scene box"
        if params.space.contract_around == "cameras":
            box, kept = camera_box(box, np.asarray(world.centers())), "the box of the scene and the cameras"
        return ContractedSpace(box), (
            f"{why}: world rays over each image's near/far; {kept} at full resolution and the space "
            "beyond it contracted into a shell around it (mip-NeRF 360, Eq. 10), steps growing with distance")
    if layout == "forward":
        c2ws = np.array([f.c2w for f in world.frames])
        reference = world.camera_of(world.frames[0])
        near_plane = NDC_NEAR_FACTOR * min(f.near for f in bounds.frames)
        ray_space = NdcSpace(tuple(map(tuple, mean_camera(c2ws).tolist())), reference.fx,
                             (reference.width, reference.height), near_plane)
        return ray_space, (f"forward-facing: rays in NDC of the mean camera, near plane {near_plane:.3g}, "
                           "samples linear in NDC depth (near to infinity)")
    if layout == "inward360" and params.space.clip_to_box:
        return BoxSpace(scene_box(bounds)), "inward 360: world rays, each clipped to the scene box and its image's near/far"
    what = "unbounded 360: world rays over each image's near/far" if layout == "unbounded360" else "world rays over each image's near/far"
    return BoxSpace(), what + (", samples linear in disparity" if lindisp(params.sampler, layout) else "")


def scene_box(bounds: Bounds) -> Box:
    return (tuple(bounds.scene_box[0]), tuple(bounds.scene_box[1]))


def camera_box(box: Box, centers: np.ndarray, margin: float = CAMERA_MARGIN) -> Box:
    """The box around ``box`` and the camera ``centers`` (N, 3), grown by ``margin`` of its size a side: what
    the photos mostly show of a scene that goes on beyond its box (the floor they were taken from, the walls
    near them) then lies in it, at the field's full resolution, instead of in the contracted shell."""
    lo = np.minimum(np.asarray(box[0], dtype=float), centers.min(axis=0))
    hi = np.maximum(np.asarray(box[1], dtype=float), centers.max(axis=0))
    pad = (hi - lo) * margin
    return tuple((lo - pad).tolist()), tuple((hi + pad).tolist())


def field_box(ray_space: RaySpace, layout: str, bounds: Bounds) -> Box | None:
    """Where the fields and the occupancy grid live: the ray space's box (NDC: the frustum out to the farthest
    bound), else the scene box; None for unbounded scenes."""
    box = ray_space.field_box(max(f.far for f in bounds.frames) if bounds.frames else None)
    if box is None and layout != "unbounded360":
        box = scene_box(bounds)
    return box


def field_for(params: TrainSettings, box: Box | None, contracted: bool) -> tuple[FieldConfig, str | None]:
    """The field ``train.field`` configures over ``box``, with what it leaves to the space decided (``contracted``:
    whether the space beyond the scene box is contracted), and its sentence. A field that spans a box falls back
    to the MLP of Fig. 7 where the scene has none (unbounded and not contracted)."""
    field = params.field.for_space(contracted)
    if box is None and field.needs_box:
        return MlpConfig(), f"unbounded 360: the {field.kind} field needs a bounded box, so the MLP (Fig. 7) is trained"
    return field, field.describe()


def sampler_for(params: TrainSettings, box: Box | None, layout: str) -> tuple[SamplerConfig, str | None]:
    """Where rays are sampled: the sampler ``train.sampler`` configures (``auto`` was resolved with the field's
    own choice, ``nerfpipe.nerf.config.sampler_for``), its ``lindisp`` decided for the scene. A sampler that
    grids the field box needs one: without it, Section 5.2's sampling."""
    sampler, said = params.sampler, None
    if sampler.needs_box and box is None:
        sampler, said = HierarchicalConfig(), ("no occupancy grid: an unbounded scene has no box to grid; Section "
                                               "5.2's sampling instead")
    if isinstance(sampler, HierarchicalConfig):
        sampler = dataclasses.replace(sampler, lindisp="on" if lindisp(sampler, layout) else "off")
    return sampler, said or sampler.describe()


def build_background(scene: SceneDecisions) -> tuple[tuple[float, ...] | None, str]:
    """The colour renders are composited onto: the scene's backdrop (alpha or a constant colour), else none.
    A constant backdrop is also masked while training (``SceneDecisions.backdrop``, ``Trainer.backdrop_targets``)."""
    kind, color = scene.background.value, scene.background_color.value
    if kind in ("alpha", "color") and color is not None:
        background = tuple(float(c) for c in color)
        shown = ", ".join(f"{c:.2f}" for c in background)
        backdrop = scene.backdrop()
        if backdrop is None:
            return background, f"background {kind}: renders composited onto ({shown})"
        return background, (
            f"background color: the backdrop (pixels within {backdrop[1]:g} of ({shown}) joined to the image border, "
            "grown by GrabCut over what looks like them) "
            f"trains empty space against a random colour per ray; renders composited onto ({shown})")
    return None, "no background model: the background is part of the scene (composited onto black)"


def models_appearance(params: TrainSettings, scene: SceneDecisions) -> tuple[bool, str]:
    """Whether each photo's exposure and white balance is learned (``nerfpipe.nerf.appearance``): by default
    when the scene analysis found the exposure varying (EXIF, else the brightness of the same points)."""
    varies = bool(scene.exposure_varies.value)
    choice = params.per_image.appearance
    if choice != "auto":
        on = choice == "on"
        return on, f"per-image exposure and white balance {'learned' if on else 'not modelled'} (train.per_image.appearance={choice})"
    if varies:
        return True, "exposure varies across the photos: each photo's exposure and white balance is learned " \
                     "(3 gains on linear light); renders show the photos' mean exposure"
    return False, "exposure constant across the photos: no per-image appearance"


def refines_poses(params: TrainSettings, scene: SceneDecisions, world: CameraSet) -> tuple[bool, str]:
    """Whether the training cameras' poses are refined with the field (``nerfpipe.nerf.refinement``). By
    default, for photos whose poses the data cannot vouch for: sparse points that reproject with a mean error
    above ``POSE_ERROR_PX``, or no points to check the poses by (a phone's or another tool's poses). Not for
    poses whose points reproject within it: on the beer capture (COLMAP, 0.75 px) refining measured 0.2 dB
    worse and on the temple (calibrated, 0.36 px) no better, at a third more training time; on the cup
    (LLFF poses, points triangulated with them at 1.29 px) 0.6 dB worse in 150 s (24.7 against 25.3 dB), so
    the line is at 2 px. Not for rendered captures (photos with alpha), whose poses are exact by construction."""
    choice = params.per_image.refine_poses
    if choice != "auto":
        on = choice == "on"
        return on, f"camera poses {'refined' if on else 'kept as given'} (train.per_image.refine_poses={choice})"
    if scene.background.value == "alpha":
        return False, "rendered capture (photos with alpha): its camera poses are exact and kept as given"
    points = world.points
    if points is None or not len(points.error):
        return True, ("no sparse points to check the camera poses by: each training camera's pose is refined with the "
                      "field (rotation and translation, centred)")
    error = float(np.mean(points.error))
    if error > POSE_ERROR_PX:
        return True, (f"sparse points reproject with a mean error of {error:.2f} px (> {POSE_ERROR_PX:g} px): each "
                      "training camera's pose is refined with the field (rotation and translation, centred)")
    return False, (f"sparse points reproject within {error:.2f} px on average (<= {POSE_ERROR_PX:g} px): camera poses "
                   "kept as given (train.per_image.refine_poses=on refines them)")


def carves(params: TrainSettings, scene: SceneDecisions, silhouettes: Silhouettes | None) -> bool:
    """Whether the visual hull of the silhouettes bounds the scene: with silhouettes (alpha, a backdrop) and
    a scene box that is the field's box (not NDC's frustum, not a contracted space). ``auto`` and ``on``
    carve alike; ``on`` also says why when it cannot (``build_model``)."""
    return (params.space.hull != "off" and silhouettes is not None and scene.layout.value == "inward360"
            and not contracts(params, scene))


def carve_scene_box(params: TrainSettings, bounds: Bounds, silhouettes: Silhouettes,
                    points: np.ndarray | None = None) -> tuple[Bounds, str]:
    """``bounds`` with its scene box shrunk to the box of the silhouettes' visual hull
    (``nerfpipe.geometry.hull``), so that the grids spend their cells on the object, and what it did.

    ``points``: (N, 3) sparse points in the world. A mask that calls part of the object backdrop in a few
    photos would carve it away; the box never shrinks past the robust box of what SfM triangulated."""
    lo, hi = bounds.box()
    tight = hull_box(silhouettes.hull((lo, hi), HULL_RESOLUTION, params.space.hull_tolerance), (lo, hi))
    if tight is None:
        return bounds, (f"visual hull: the {len(silhouettes.masks)} silhouettes leave nothing of the scene box standing; "
                        "the box is kept (train.space.hull=off turns carving off)")
    kept = ""
    if points is not None and len(points):
        p_lo, p_hi = robust_box(points)
        grown = (np.maximum(np.minimum(tight[0], p_lo), lo), np.minimum(np.maximum(tight[1], p_hi), hi))
        if not (np.allclose(grown[0], tight[0]) and np.allclose(grown[1], tight[1])):
            tight, kept = grown, ", kept around the sparse points"
    shrunk = dataclasses.replace(bounds, scene_box=(tight[0].tolist(), tight[1].tolist()))

    def size(a: np.ndarray, b: np.ndarray) -> str:
        return " x ".join(f"{v:.2f}" for v in b - a)

    volume = float(np.prod(tight[1] - tight[0]) / np.prod(hi - lo))
    return shrunk, (f"visual hull of {len(silhouettes.masks)} silhouettes: the scene box shrinks from {size(lo, hi)} "
                    f"to {size(*tight)} ({100 * volume:.0f}% of its volume{kept}), the grids' cells with it")


def resolve_spec(params: TrainSettings, scene: SceneDecisions, world: CameraSet, bounds: Bounds,
                 train_names: list[str] | None = None,
                 silhouettes: Silhouettes | None = None) -> tuple[ModelSpec, list[str]]:
    """The model this scene calls for, as a spec, and a sentence per choice: the ray space, field, sampler
    and background. With ``train_names``, the training images in order, also their exposure gains
    (starting from the exposures the scene measured) and pose corrections where the scene calls for them
    (``models_appearance``, ``refines_poses``). With the training photos' ``silhouettes``, the scene box
    shrinks to the box of their visual hull (``carves``)."""
    layout = scene.layout.value
    hull_said = None
    if carves(params, scene, silhouettes):
        points = None if world.points is None else np.asarray(world.points.xyz)
        bounds, hull_said = carve_scene_box(params, bounds, silhouettes, points)
    elif params.space.hull == "on":
        hull_said = ("train.space.hull=on: the scene box is kept, since a visual hull needs inward 360 photos with "
                     "silhouettes (alpha or a backdrop) and a scene box that is not contracted")
    ray_space, ray_said = build_ray_space(params, scene, world, bounds)
    box = field_box(ray_space, layout, bounds)
    field, field_said = field_for(params, box, contracts(params, scene))
    sampler, sampler_said = sampler_for(params, box, layout)
    two = field.two_fields and sampler.fields() == 2
    background, background_said = build_background(scene)
    noise = density_noise(params, layout)
    decisions = [
        hull_said, ray_said, field_said, sampler_said, background_said,
        "linear RAW: trained on linear values; previews are sRGB-encoded" if scene.photometric.value == "linear_raw" else None,
        f"noise of std {noise:g} on raw density while training" if noise else None,
    ]
    appearance = refinement = None
    if train_names:
        (with_appearance, appearance_said), (with_refinement, refinement_said) = \
            models_appearance(params, scene), refines_poses(params, scene, world)
        decisions += [appearance_said, refinement_said]
        known = scene.exposure_varies.measured.get("stops") or {}
        stops = [float(known.get(name, 0.0)) for name in train_names] if known else None
        if with_appearance:
            appearance = {"images": len(train_names), "linear": scene.photometric.value == "linear_raw", "stops": stops}
        refinement = {"images": len(train_names)} if with_refinement else None
    info = {"layout": layout, "photometric": scene.photometric.value, "to_sfm": bounds.to_sfm}
    spec = ModelSpec(field=field, sampler=sampler, ray_space=ray_space, box=box, fine_network=two, background=background,
                     appearance=appearance, refinement=refinement, info=info)
    return spec, [d for d in decisions if d is not None]


def build_model(params: TrainSettings, scene: SceneDecisions, world: CameraSet, bounds: Bounds,
                device: torch.device, train_names: list[str] | None = None,
                silhouettes: Silhouettes | None = None) -> tuple[RadianceModel, list[str]]:
    """``build`` of ``resolve_spec``: the untrained model this scene calls for, seeded, and the sentences."""
    spec, decisions = resolve_spec(params, scene, world, bounds, train_names, silhouettes)
    torch.manual_seed(params.seed)
    return build(spec, device), decisions

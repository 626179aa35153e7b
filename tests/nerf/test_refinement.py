"""Camera refinement: identity at the start, corrections about each camera's centre, the gauge, the error."""

from __future__ import annotations

import math

import numpy as np
import torch
from kornia.geometry.liegroup import So3

from nerfpipe.nerf.refinement import PoseRefinement, rotation_error_deg
from tests.helpers import look_at


def poses(n: int) -> torch.Tensor:
    eyes = [(4 * math.cos(a), 4 * math.sin(a), 1.0) for a in torch.linspace(0, 6, n).tolist()]
    return torch.tensor(np.array([look_at(np.array(e), np.zeros(3)) for e in eyes]), dtype=torch.float32)


def test_no_correction_at_the_start() -> None:
    c2w = poses(5)
    assert torch.equal(PoseRefinement(5)(c2w), c2w)
    rotation, translation = PoseRefinement(5).moved()
    assert rotation.abs().max() == 0 and translation.abs().max() == 0


def test_a_correction_turns_a_camera_about_its_centre_and_moves_it() -> None:
    c2w = poses(2)
    refinement = PoseRefinement(2)
    w = torch.tensor([0.0, 0.0, math.radians(2.0)])
    t = torch.tensor([0.1, 0.0, 0.0])
    with torch.no_grad():  # +/- the same: centred, image 0 turns by +2 degrees and image 1 by -2
        refinement.tangent[0] = torch.cat([w, t])
        refinement.tangent[1] = -torch.cat([w, t])
    refined = refinement(c2w)
    assert torch.allclose(refined[0, :3, 3], c2w[0, :3, 3] + t, atol=1e-6)
    assert torch.allclose(refined[0, :3, :3], So3.exp(w[None]).matrix()[0] @ c2w[0, :3, :3], atol=1e-6)
    assert torch.allclose(rotation_error_deg(c2w.double(), refined.double()), torch.tensor([2.0, 2.0], dtype=torch.float64), atol=1e-4)
    rotation, translation = refinement.moved()
    assert torch.allclose(rotation, torch.tensor([2.0, 2.0]), atol=1e-4) and torch.allclose(translation, torch.tensor([0.1, 0.1]))


def test_a_correction_shared_by_every_camera_is_the_gauge_and_changes_nothing() -> None:
    c2w = poses(4)
    refinement = PoseRefinement(4)
    with torch.no_grad():
        refinement.tangent[:] = torch.tensor([0.1, -0.2, 0.05, 0.3, 0.0, -0.1])
    assert torch.allclose(refinement(c2w), c2w, atol=1e-6)
    assert float(refinement.penalty().detach()) < 1e-12

"""The NeRF of Mildenhall et al. 2020 as pure tensor functions and thin modules, in sub-packages by role.

Nothing here knows about the stages. Section and equation numbers refer to the ECCV 2020 paper, "NeRF:
Representing Scenes as Neural Radiance Fields for View Synthesis".

- ``fields/``: (x, d) -> (rgb, sigma): ``grid`` (dense grids after Instant-NGP), ``hash``, ``planes`` and
  ``mlp`` (Section 3 / Fig. 7), each kind's settings in ``configs``; ``encoding`` (Eq. 4).
- ``samplers/``: where along a ray to evaluate the field: ``marching`` an occupancy grid (``occupancy``,
  ``march``) or Section 5.2's ``hierarchical`` sampling (``sampling``: Eq. 2 and Eq. 5).
- ``spaces/``: rays (Section 4, NDC) in the coordinates a field lives in: ``ray_space`` (box, NDC,
  contracted), ``contraction``, ``rays``.
- ``render/``: ``volume``, the one compositing of packed samples (Eq. 3, Eq. 5).
- ``model``: ``RadianceModel``, its one ``render``, built from a ``spec.ModelSpec`` (``build``) and loaded
  from its files; ``appearance`` and ``refinement``, what is learned per photo.
- ``policy``: the scene's decisions and the train parameters resolved into a ``ModelSpec``: the one place
  that chooses parts. ``registry``: the parts by kind. ``config``: the train groups that are not a part's own.
- ``train/``: ``trainer`` (Section 5.3), ``checkpoints``, the ``stall`` guard, ``images`` (held-out splits,
  training pixels), ``evaluation`` (held-out PSNR / SSIM); ``throughput``: what rendering costs, timed first.
- ``device`` and ``cpu``: where and how torch runs.
"""

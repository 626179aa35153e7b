"""The NeRF of Mildenhall et al. 2020 as pure tensor functions and thin modules.

Nothing here knows about the stages: ``rays`` (camera and NDC rays), ``encoding`` (positional encoding,
Eq. 4), ``sampling`` (stratified sampling, Eq. 2, and inverse transform sampling, Eq. 5), ``rendering``
(alpha compositing, Eq. 3 and 5), ``field`` (the MLP of Section 3 / Fig. 7) and ``renderer`` (coarse +
fine rendering of a batch of rays, Section 5.2). Section and equation numbers refer to the ECCV 2020 paper,
"NeRF: Representing Scenes as Neural Radiance Fields for View Synthesis".

A model is parts behind small protocols, named in ``registry``: fields (``fields``: ``grid_field``, dense
grids after Instant-NGP, and ``field``), samplers (``samplers``: marching an occupancy grid, ``occupancy``
and ``marching``, or Section 5.2's ``renderer``) and a ray space (``ray_space``: NDC, box, ``contraction``).
``config`` holds the train stage's parameter groups; ``assembly`` resolves a scene's decisions and those
parameters into a ``spec.ModelSpec``, and ``model.build`` makes the ``model.RadianceModel`` from it (and
loads it from its files). Around them: ``trainer`` (the optimization of Section 5.3, with ``checkpoints``
and the ``stall`` guard), ``images`` (held-out splits and training pixels), ``evaluation`` (held-out PSNR /
SSIM within a time budget), ``appearance`` (each photo's exposure and white balance) and ``refinement``
(each camera's pose correction), ``device`` and ``cpu`` (where and how torch runs).
"""

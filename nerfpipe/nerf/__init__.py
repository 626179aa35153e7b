"""The NeRF of Mildenhall et al. 2020 as pure tensor functions and thin modules.

Nothing here knows about the stages: ``rays`` (camera and NDC rays), ``encoding`` (positional encoding,
Eq. 4), ``sampling`` (stratified sampling, Eq. 2, and inverse transform sampling, Eq. 5), ``rendering``
(alpha compositing, Eq. 3 and 5), ``field`` (the MLP of Section 3 / Fig. 7) and ``renderer`` (coarse +
fine rendering of a batch of rays, Section 5.2). Section and equation numbers refer to the ECCV 2020 paper,
"NeRF: Representing Scenes as Neural Radiance Fields for View Synthesis".

Around them: ``grid_field`` and ``occupancy`` (dense grids and empty-space skipping, after Instant-NGP),
``model`` (the trained model and its files), ``trainer`` (the optimization of Section 5.3), ``assembly``
(the model and training configuration a scene's decisions call for), ``images`` (held-out splits and
training pixels), ``evaluation`` (held-out PSNR / SSIM), ``appearance`` (each photo's exposure and white
balance) and ``refinement`` (each camera's pose correction), learned with the field where the scene calls for
them, ``contraction`` (unbounded space), ``device`` and ``cpu`` (where and how torch runs).
"""

"""The NeRF of Mildenhall et al. 2020 as pure tensor functions and thin modules.

Nothing here knows about the pipeline: ``rays`` (camera and NDC rays), ``encoding`` (positional encoding,
Eq. 4), ``sampling`` (stratified sampling, Eq. 2, and inverse transform sampling, Eq. 5), ``rendering``
(alpha compositing, Eq. 3 and 5), ``field`` (the MLP of Section 3 / Fig. 7) and ``renderer`` (coarse +
fine rendering of a batch of rays, Section 5.2). Section and equation numbers refer to the ECCV 2020 paper,
"NeRF: Representing Scenes as Neural Radiance Fields for View Synthesis".
"""

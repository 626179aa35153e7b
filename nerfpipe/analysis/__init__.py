"""The scene analyses: what the photos and their cameras say about the scene, each a decision with its
evidence. ``layout`` (forward-facing, inward 360, unbounded), ``background`` (alpha, a constant backdrop,
or part of the scene), ``lens`` (distortion left after undistortion) and ``exposure`` (RAW developed
linearly, exposure varying across the photos). The scene stage runs them and records what they decided;
each takes the thresholds it needs, so they can be called and tested without the pipeline."""

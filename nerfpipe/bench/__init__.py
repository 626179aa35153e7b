"""`nerfpipe bench`: held-out accuracy against training time for the train presets and the paper's ablations."""

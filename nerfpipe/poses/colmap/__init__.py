"""COLMAP through pycolmap, in process: feature extraction and matching (``matching``), incremental or
global mapping (``mapping``), and points triangulated for known poses (``triangulate``), with COLMAP's log
captured to a file (``log``). Importing these modules imports pycolmap: the sfm stage imports them when it
runs, so a machine without pycolmap can still train and render from a cached run."""

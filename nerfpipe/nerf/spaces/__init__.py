"""Ray spaces: the rays of a camera (``rays``) in the coordinates a field lives in (``ray_space``: a box, NDC, or
space contracted around a box, ``contraction``)."""

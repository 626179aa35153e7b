"""Getting things out of a trained radiance field: depth maps, point clouds, meshes, camera paths,
videos and screenshots. Functions here take arrays, tensors and models; the export stages call them."""

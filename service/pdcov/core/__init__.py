"""The pure core: camera, frames, poses, mount geometry, footprint, detector model, domain,
grid, geodesy, search theory. numpy, OpenCV, shapely and pymap3d in, values out; no I/O of its
own beyond the files it is handed."""

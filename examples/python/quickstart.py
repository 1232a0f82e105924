"""wonder3d from Python, start to finish, with nothing to download.

Run from the repository root, with the wheel installed (docs/python.md):

    python examples/python/quickstart.py [OUT_DIR]

1. a mesh → oracle views → reconstruction → metrics → texture → GLB and trimesh;
2. a photo (here spot's front view, as RGBA) → the small model trained here → views → mesh.
"""

import pathlib
import sys

import numpy as np

import wonder3d

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "quickstart_out")
out.mkdir(exist_ok=True)

# 1. From views of a known mesh.
spot = wonder3d.Mesh.load("assets/spot.obj")
views = wonder3d.render_views(spot, size=256)
print(views)
mesh = wonder3d.reconstruct(views, preset="fast", progress=wonder3d.tqdm_progress(leave=False))
metrics = wonder3d.evaluate(mesh, spot)
print(f"{mesh}: chamfer {metrics['chamfer']:.4f}, F@0.02 {metrics['fscore_0.02']:.3f}")
textured = wonder3d.texture(mesh, views, size=1024)
textured.save(out / "spot.glb")
try:
    print("trimesh:", textured.to_trimesh())
except ImportError:
    print("(pip install trimesh pillow for Mesh.to_trimesh)")

# 2. From a photo: an RGBA array whose alpha masks the object (a path or a PIL image works too).
front = views.names.index("front")
photo = np.dstack([views.colours[front], views.masks[front]])
generator = wonder3d.Generator("assets/model-small")
output = wonder3d.Pipeline(generator, preset="fast", texture_size=512).run(
    photo, progress=wonder3d.tqdm_progress(leave=False)
)
output.save(out / "from_photo.glb")
print(f"from the photo: {output.mesh}, {output.report['seconds']['total']:.1f} s -> {out / 'from_photo.glb'}")

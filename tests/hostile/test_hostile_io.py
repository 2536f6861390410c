"""Hostile inputs to voxax.io beyond the core's table, each case in its own process (see
`_hostile_driver`)."""

from __future__ import annotations

from _table import table

PLY = ("open('m.ply', 'wb').write(b'ply\\nformat ascii 1.0\\nelement vertex {nv}\\nproperty float x\\n"
       "property float y\\nproperty float z\\nelement face {nf}\\nproperty list uchar int vertex_indices\\n"
       "end_header\\n{body}');")
BODY = "0 0 0\\n1 0 0\\n0 1 0\\n3 0 1 2\\n"
CASES = [
    ("io.save", "Inf vertices", "voxax.io.save((V + np.inf, F), 'x.obj')", "ValueError", "NaN or Inf"),
    ("io.save", "bool vertices", "voxax.io.save((V > 0, F), 'x.ply')", "TypeError", "`vertices`"),
    ("io.save", "faces past the vertices", "voxax.io.save((V, F + len(V)), 'x.ply')", "ValueError", "out of range"),
    ("io.save", "unknown extension", "voxax.io.save(BALL, 'x.nope')", "ValueError", "nope"),
    ("io.save", "no extension (a folder's name)", "voxax.io.save(BALL, '.')", "ValueError",
     "voxax.io.save: `path` must end in a mesh file extension"),
    ("io.save", "into a missing folder", "voxax.io.save(BALL, 'no/such/folder/x.obj')", "FileNotFoundError",
     "voxax.io.save: cannot write 'no/such/folder/x.obj'"),
    ("io.save", "PLY into a missing folder", "voxax.io.save(BALL, 'no/such/folder/x.ply')", "FileNotFoundError",
     "voxax.io.save: cannot write"),
    ("io.save", "a path that is an int", "voxax.io.save(BALL, 3)", "TypeError", "`path` must be a file path"),
    ("io.save", "a 2D polygon", "voxax.io.save(voxax.data.polygon_square(), 'p.obj')", "ValueError",
     "voxax.io.save: `mesh` must be a single 3D triangle mesh"),
    ("io.save", "round trip at 1e70 (oracle)",
     "voxax.io.save((V * 1e70, F), 'big.ply'); m = voxax.io.load('big.ply');"
     "assert np.allclose(np.asarray(m.vertices), V * 1e70, rtol=1e-6) and (np.asarray(m.faces) == F).all()", None, ""),
    ("io.load", "a face index beyond V", PLY.format(nv=3, nf=1, body="0 0 0\\n1 0 0\\n0 1 0\\n3 0 1 7\\n")
     + "voxax.io.load('m.ply')", "ValueError", "out of range"),
    ("io.load", "NaN vertices", PLY.format(nv=3, nf=1, body="nan 0 0\\n1 0 0\\n0 1 0\\n3 0 1 2\\n")
     + "voxax.io.load('m.ply')", "ValueError", "NaN or Inf"),
    ("io.load", "a header claiming 10^12 vertices", PLY.format(nv=10**12, nf=1, body=BODY)
     + "voxax.io.load('m.ply')", "ValueError", "its header claims 1000000000000 vertices"),
    ("io.load", "a header claiming more vertices than the file holds", PLY.format(nv=2000, nf=1, body=BODY)
     + "voxax.io.load('m.ply')", "ValueError", "truncated or corrupt: its header claims more elements"),
    ("io.load", "a header claiming one vertex more than the file holds",
     PLY.format(nv=4, nf=1, body="0.000 0.000 0.000\\n1.000 0.000 0.000\\n0.000 1.000 0.000\\n3 0 1 2\\n")
     + "voxax.io.load('m.ply')", "ValueError", "truncated or corrupt: its header claims 4 vertices and 1 faces"),
    ("io.load", "a directory", "import os; os.makedirs('d.ply', exist_ok=True); voxax.io.load('d.ply')", "ValueError",
     "not a file"),
    ("io.load", "a number for the path", "voxax.io.load(3)", "TypeError", "`path`"),
    ("io.load", "a one-triangle file (oracle)", PLY.format(nv=3, nf=1, body=BODY)
     + "m = voxax.io.load('m.ply'); assert np.asarray(m.faces).tolist() == [[0, 1, 2]]", None, ""),
    ("io.normalize", "NaN mesh", "voxax.io.normalize((VNAN, F))", "ValueError", "NaN"),
    ("io.normalize", "negative max_abs", "voxax.io.normalize(BALL, -1.0)", "ValueError", "max_abs"),
    ("io.normalize", "a tiny mesh (oracle)",
     "m = voxax.io.normalize((V * 1e-70, F), 0.8); assert np.isclose(np.abs(np.asarray(m.vertices)).max(), 0.8)",
     None, ""),
    ("io.as_arrays", "a path", "voxax.io.as_arrays('x.ply')", "TypeError", "voxax.io.load"),
    ("io.as_arrays", "complex vertices", "voxax.io.as_arrays((V + 0j, F))", "TypeError", "complex"),
    ("io.is_watertight", "faces past the vertices", "voxax.io.is_watertight(V, F + len(V))", "ValueError",
     "out of range"),
    ("io.is_watertight", "open and closed (oracle)",
     "assert voxax.io.is_watertight(V, F) and not voxax.io.is_watertight(V, F[:-1])", None, ""),
    ("io.normalize", "a mesh too small to scale (subnormal)", "voxax.io.normalize((V * 1e-310, F))", "ValueError",
     "voxax.io.normalize: the mesh is too small to scale"),
    ("io.normalize", "under jit", "jax.jit(lambda v: voxax.io.normalize((v, F)))(V)", "TypeError",
     "voxax.io.normalize: computes eagerly on the host"),
]

outcomes, test_hostile_input = table(CASES)

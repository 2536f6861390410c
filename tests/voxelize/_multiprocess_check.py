"""Sharded voxelization across two processes (jax.distributed on localhost, CPU collectives),
run by tests/voxelize/test_sharded.py: `python _multiprocess_check.py PORT PROCESS_ID OUT.npz`.

Each process owns one CPU device; the grid is split in two slabs along x. Each process
saves its own slab of the grid and the (replicated) gradient of an energy of the whole
grid, which needs a sum across the processes.

Then a memory budget: a 256^3 float32 grid (64 MiB) is voxelized sharded, and each process
records how much its resident memory grew while running the compiled call (the peak is
reset after compilation through /proc/self/clear_refs). The test gives each process a budget
smaller than the whole grid.
"""

import sys

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_cpu_collectives_implementation", "gloo")

port, pid, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
jax.distributed.initialize(coordinator_address=f"localhost:{port}", num_processes=2, process_id=pid,
                           initialization_timeout=120)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding  # noqa: E402
from jax.sharding import PartitionSpec as P  # noqa: E402

import voxax  # noqa: E402

GRID = voxax.Grid(lower=(-0.9, -1.0, -0.8), upper=(1.0, 0.9, 1.1), shape=(8, 7, 6))

m = voxax.data.icosphere(2, radius=0.7)
v = jnp.asarray(m.vertices + np.array([0.3, 0.0, 0.1]))
c = np.random.default_rng(0).normal(size=GRID.shape)
assert jax.device_count() == 2 and jax.local_device_count() == 1, jax.devices()
mesh = Mesh(np.array(jax.devices()), ("x",))
W = voxax.voxelize_sharded(v, m.faces, GRID, mesh, "x")
(local,) = W.addressable_shards
cs = jax.make_array_from_callback(GRID.shape, NamedSharding(mesh, P("x")), lambda idx: c[idx])
g = jax.jit(jax.grad(lambda x, cc: jnp.sum(cc * jnp.sin(voxax.voxelize_sharded(x, m.faces, GRID, mesh, "x")))))(v, cs)


def _status(key):
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    raise RuntimeError(key)


BIG = voxax.Grid.cube(256)
big_mesh = voxax.data.icosphere(3, radius=0.7)
vb = jnp.asarray(big_mesh.vertices, jnp.float32)
compiled = jax.jit(lambda x: voxax.voxelize_sharded(x, big_mesh.faces, BIG, mesh, "x")).lower(vb).compile()
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")  # resets the peak resident set size (VmHWM) to the current one
before = _status("VmRSS")
Wb = compiled(vb)
Wb.block_until_ready()
peak = _status("VmHWM") - before
(big_local,) = Wb.addressable_shards
np.savez(out, slab=np.asarray(local.data), start=local.index[0].start, grad=np.asarray(g.addressable_data(0)),
         big_slab=np.asarray(big_local.data), big_start=big_local.index[0].start, big_peak=peak)
jax.distributed.shutdown()
print("done", pid)

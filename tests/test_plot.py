"""voxax.plot: figure contents (Agg backend): axes, image data, colour limits, polygons."""

import sys

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import voxax  # noqa: E402
from voxax import plot  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def torus_grid():
    mesh = voxax.data.torus()
    grid = voxax.Grid.cube(24)
    return mesh, grid, np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))


def _sorted_rows(a):
    a = np.asarray(a)
    return a[np.lexsort(a.T[::-1])]


def _images(fig):
    return [ax.images[0] for ax in fig.axes if ax.images]


# -- slices ------------------------------------------------------------------------------


def test_slices_image_data_is_the_slice_and_limits_are_symmetric(torus_grid):
    mesh, grid, W = torus_grid
    W = W - 0.3  # make it visibly signed and asymmetric
    fig = plot.slices(W, grid, axis=2, count=3)
    images = _images(fig)
    assert len(images) == 3 and len(fig.axes) == 4  # three slices and a colour bar
    for ax, im in zip(fig.axes, images):
        k = int(ax.get_title().split()[2])
        np.testing.assert_array_equal(np.asarray(im.get_array()), W[:, :, k].T)
        lo, hi = im.get_clim()
        assert lo == -hi and hi == pytest.approx(np.abs(W).max())
        assert im.get_extent() == [-1.0, 1.0, -1.0, 1.0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x", "y")
    assert images[0].get_cmap().name == "RdBu_r"


def test_slices_picks_the_thinnest_axis_and_keeps_the_cli_signature(tmp_path):
    # A flat box, thin along y: the automatic axis is y, and the CLI's call works.
    box = voxax.data.box((-0.6, -0.1, -0.6), (0.6, 0.1, 0.6))
    grid = voxax.Grid.cube(16)
    W = voxax.voxelize(box.vertices, box.faces, grid)
    path = tmp_path / "s.png"
    fig = plot.slices(W, grid, axis=None, count=4, title="demo", path=str(path))
    assert path.stat().st_size > 0
    assert fig._suptitle.get_text() == "demo"
    assert all(ax.get_title().startswith("y index") for ax in fig.axes[:-1])
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes[:1]] == [("x", "z")]


def test_slices_2d_and_explicit_vmax():
    sq = voxax.data.polygon_square()
    grid = voxax.Grid.cube(12, dim=2)
    W = np.asarray(voxax.voxelize(sq.vertices, sq.faces, grid))
    fig = plot.slices(W, vmax=2.0)
    (im,) = _images(fig)
    np.testing.assert_array_equal(np.asarray(im.get_array()), W.T)
    assert im.get_clim() == (-2.0, 2.0)


def test_slices_rejects_bad_input():
    with pytest.raises(ValueError, match="2D or 3D"):
        plot.slices(np.zeros(5))
    with pytest.raises(ValueError, match="grid has shape"):
        plot.slices(np.zeros((4, 4, 4)), voxax.Grid.cube(5))
    with pytest.raises(ValueError, match="axis"):
        plot.slices(np.zeros((4, 4, 4)), axis=3)


# -- silhouettes -------------------------------------------------------------------------


def test_silhouettes_max_and_mellowmax(torus_grid):
    mesh, grid, W = torus_grid
    fig = plot.silhouettes(W, grid, method="max")
    images = _images(fig)
    assert len(images) == 3 and len(fig.axes) == 4
    for a, im in enumerate(images):
        np.testing.assert_array_equal(np.asarray(im.get_array()), W.max(axis=a).T)
        lo, hi = im.get_clim()
        assert lo == -hi
    labels = [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes[:3]]
    assert labels == [("y", "z"), ("x", "z"), ("x", "y")]

    fig = plot.silhouettes(W, grid, w=50.0)
    soft = voxax.energies.silhouettes(jnp.asarray(W), 50.0)
    for im, S in zip(_images(fig), soft):
        np.testing.assert_allclose(np.asarray(im.get_array()), np.asarray(S).T, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="method"):
        plot.silhouettes(W, method="min")
    with pytest.raises(ValueError, match="3D grid"):
        plot.silhouettes(W[0])


def test_projections_rows_per_grid_shared_range_and_titles(torus_grid, tmp_path):
    mesh, grid, W = torus_grid
    doubled = 2 * W
    fig = plot.projections([W, doubled], grid, labels=["before", "after"], path=tmp_path / "p.png")
    images = _images(fig)
    assert len(images) == 6 and len(fig.axes) == 7  # two rows of three and a colour bar
    for r, G in enumerate((W, doubled)):
        for a in range(3):
            im = images[3 * r + a]
            np.testing.assert_array_equal(np.asarray(im.get_array()), G.max(axis=a).T)
            assert im.get_clim() == (0.0, pytest.approx(doubled.max()))  # one range for all
            assert im.get_extent() == [-1.0, 1.0, -1.0, 1.0]
    assert fig.axes[4].get_title() == f"after: max of W along y ({doubled.max():.3f})"
    assert [(ax.get_xlabel(), ax.get_ylabel()) for ax in fig.axes[:3]] == [("y", "z"), ("x", "z"), ("x", "y")]
    assert (tmp_path / "p.png").stat().st_size > 0
    # One grid; the range is at least [0, 1] so that values above 1 stand out.
    fig = plot.projections(0.5 * W)
    assert len(_images(fig)) == 3 and _images(fig)[0].get_clim() == (0.0, 1.0)
    assert fig.axes[0].get_title().startswith("0: max of W along x")
    with pytest.raises(ValueError, match="3D grids"):
        plot.projections([W[0]])
    with pytest.raises(ValueError, match="differ in shape"):
        plot.projections([W, W[:-1]])
    with pytest.raises(ValueError, match="labels"):
        plot.projections([W, W], labels=["one"])


def test_pyplot_is_headless_outside_ipython():
    plt = plot.pyplot()
    assert plt is matplotlib.pyplot
    assert matplotlib.get_backend().lower() == "agg"


# -- meshes ------------------------------------------------------------------------------


def test_mesh_one_polygon_per_face_coloured_by_vertex_values():
    m = voxax.data.icosphere(1)
    values = m.vertices[:, 2]
    fig = plot.mesh(m.vertices, m.faces, values=values, shade=False, cmap="viridis", label="z")
    ax = fig.axes[0]
    assert ax.name == "3d" and len(fig.axes) == 2  # the mesh and a colour bar
    coll = ax.collections[0]
    fig.canvas.draw()  # 3D polygons are projected (and depth-sorted) when drawn
    assert len(coll.get_paths()) == m.n_faces
    face = values[m.faces].mean(axis=1)
    norm = matplotlib.colors.Normalize(values.min(), values.max())
    expected = matplotlib.colormaps["viridis"](norm(face))
    # (matplotlib reorders the faces by depth when drawing: compare the sorted colours)
    np.testing.assert_allclose(_sorted_rows(coll.get_facecolor()), _sorted_rows(expected), atol=1e-6)
    assert fig.axes[1].get_ylabel() == "z"
    # Equal scales on all axes.
    spans = [np.ptp(lim) for lim in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    assert spans[0] == pytest.approx(spans[1]) == pytest.approx(spans[2])


def test_mesh_displacement_vectors_face_values_and_plain():
    m = voxax.data.icosphere(1)
    moved = m.vertices * 1.25
    fig = plot.mesh(moved, m.faces, values=moved - m.vertices, shade=False)
    colours = fig.axes[0].collections[0].get_facecolor()  # every displacement has length 0.25
    np.testing.assert_allclose(colours, np.tile(colours[0], (m.n_faces, 1)), atol=0.01)
    lo, hi = fig.axes[1].get_ylim()
    assert lo < 0.25 < hi and hi - lo < 1e-2
    per_face = np.arange(m.n_faces, dtype=float)
    fig = plot.mesh(m.vertices, m.faces, values=per_face, shade=False, vmin=0, vmax=m.n_faces - 1)
    colours = fig.axes[0].collections[0].get_facecolor()
    expected = matplotlib.colormaps["viridis"](per_face / (m.n_faces - 1))
    np.testing.assert_allclose(_sorted_rows(colours), _sorted_rows(expected), atol=1e-6)
    fig = plot.mesh(m.vertices, m.faces, color="red", shade=False)
    assert len(fig.axes) == 1
    np.testing.assert_allclose(fig.axes[0].collections[0].get_facecolor(), [[1, 0, 0, 1]] * m.n_faces)
    with pytest.raises(ValueError, match="`values` must have shape"):
        plot.mesh(m.vertices, m.faces, values=np.zeros(7))
    with pytest.raises(ValueError, match="face indices"):
        plot.mesh(m.vertices, m.faces + m.n_vertices)


def test_mesh_2d_polyline_and_into_existing_axes():
    c = voxax.data.circle_polyline(16)
    fig, ax = plt.subplots()
    out = plot.mesh(c.vertices, c.faces, values=c.vertices[:, 0], ax=ax)
    assert out is fig
    assert len(ax.collections[0].get_segments()) == c.n_faces


# -- gradients ---------------------------------------------------------------------------


def test_gradient_field_2d_arrows_follow_the_gradient():
    c = voxax.data.circle_polyline(24, 0.5)
    grid = voxax.Grid.cube(16, dim=2)
    W = voxax.voxelize(c.vertices, c.faces, grid)
    g = jax.grad(lambda v: voxax.voxelize(v, c.faces, grid).sum())(jnp.asarray(c.vertices))
    fig = plot.gradient_field(c.vertices, c.faces, g, W, grid, scale=2.0)
    ax = fig.axes[0]
    np.testing.assert_array_equal(np.asarray(ax.images[0].get_array()), np.asarray(W).T)
    (quiver,) = [a for a in ax.get_children() if isinstance(a, matplotlib.quiver.Quiver)]
    np.testing.assert_allclose(quiver.U, 2.0 * np.asarray(g)[:, 0])
    np.testing.assert_allclose(quiver.V, 2.0 * np.asarray(g)[:, 1])
    # d(volume)/dv points outwards.
    assert np.all(np.sum(np.asarray(g) * c.vertices, axis=1) > 0)


def test_gradient_field_3d_and_bad_shapes():
    m = voxax.data.icosphere(0, radius=0.5)
    g = np.ones_like(m.vertices)
    fig = plot.gradient_field(m.vertices, m.faces, g, normalize=True)
    assert fig.axes[0].name == "3d"
    with pytest.raises(ValueError, match="`gradient` must have"):
        plot.gradient_field(m.vertices, m.faces, g[:-1])


# -- histories ---------------------------------------------------------------------------


def test_history_from_minimize_result_dict_and_array(tmp_path):
    quad = lambda y, args: jnp.sum((y - 1.0) ** 2)  # noqa: E731
    r = voxax.minimize(quad, jnp.zeros(3), learning_rate=0.1, progress=False, stop=voxax.StopRules(max_steps=30))
    fig = plot.history(r, path=str(tmp_path / "h.png"))
    assert [ax.get_ylabel() for ax in fig.axes] == ["energy", "step_size"]
    x, y = fig.axes[0].lines[0].get_data()
    np.testing.assert_array_equal(y, r.history["energy"])
    np.testing.assert_array_equal(x, np.arange(1, r.steps + 1))
    assert fig.axes[0].get_yscale() == "log"  # spans more than two decades
    fig = plot.history(r, keys="energy", x="time", log=False)
    assert len(fig.axes) == 1 and fig.axes[0].get_yscale() == "linear"
    np.testing.assert_array_equal(fig.axes[0].lines[0].get_xdata(), r.history["time"])
    fig = plot.history({"energy": [3.0, 2.0, 1.0], "max_w": [1.2, 1.1, 1.0], "time": [0, 1, 2]})
    assert [ax.get_ylabel() for ax in fig.axes] == ["energy", "max_w"]
    fig = plot.history(np.array([1.0, 0.5]))
    assert len(fig.axes) == 1
    with pytest.raises(KeyError, match="no series"):
        plot.history(r, keys=["nope"])
    with pytest.raises(ValueError, match="'step' or 'time'"):
        plot.history(r, x="epoch")


def test_report_plot_history_draws_every_series():
    report = voxax.apps.Report(
        energy_history=np.array([4.0, 2.0, 1.0]),
        history={"energy": np.array([4.0, 2.0, 1.0]), "max_w": np.array([2.0, 1.5, 1.0]), "time": np.arange(3.0)},
        steps=3, stop_reason="max_steps", energy=1.0, resolution=8,
    )
    fig = report.plot_history()
    assert [ax.get_ylabel() for ax in fig.axes] == ["energy", "max_w"]
    assert fig._suptitle.get_text() == "Report: 3 steps (max_steps)"
    np.testing.assert_array_equal(fig.axes[1].lines[0].get_ydata(), [2.0, 1.5, 1.0])


def test_history_of_an_app_style_report():
    class Report:  # the shape of voxax.apps reports: energy_history + history
        energy_history = np.array([4.0, 2.0, 1.0])
        history = {"sect": np.array([3.0, 1.0, 0.5]), "max_w": np.array([2.0, 1.5, 1.0])}

    fig = plot.history(Report())
    assert [ax.get_ylabel() for ax in fig.axes] == ["energy", "sect", "max_w"]
    np.testing.assert_array_equal(fig.axes[0].lines[0].get_ydata(), Report.energy_history)


# -- plotly ------------------------------------------------------------------------------


def test_mesh_plotly_trace(tmp_path):
    pytest.importorskip("plotly")
    m = voxax.data.icosphere(1)
    fig = plot.mesh_plotly(m.vertices, m.faces, values=m.vertices[:, 2], label="z", path=tmp_path / "m.html")
    (trace,) = fig.data
    assert trace.type == "mesh3d"
    np.testing.assert_array_equal(np.asarray(trace.i), m.faces[:, 0])
    np.testing.assert_allclose(np.asarray(trace.intensity), m.vertices[:, 2])
    assert trace.intensitymode == "vertex"
    assert (tmp_path / "m.html").stat().st_size > 0
    fig = plot.mesh_plotly(m.vertices, m.faces, values=np.arange(m.n_faces, dtype=float))
    assert fig.data[0].intensitymode == "cell"


def test_mesh_plotly_missing_plotly_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "plotly", None)
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)
    m = voxax.data.icosphere(0)
    with pytest.raises(ImportError, match=r"voxax\[plot\]"):
        plot.mesh_plotly(m.vertices, m.faces)

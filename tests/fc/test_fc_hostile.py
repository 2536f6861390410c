"""Hostile input to the public fc and raster entry points: each case raises the stated error
naming the function and the argument, before any kernel runs on it."""

import dataclasses

import numpy as np
import pytest

import voxax
from voxax import fc, raster

CUBE = voxax.data.cube(1.0)
V, F = np.asarray(CUBE.vertices), np.asarray(CUBE.faces)
G = voxax.Grid.cube(8)


@pytest.fixture(scope="module")
def tok():
    return fc.encode(CUBE, G)


def _edit(tok, **kw):
    return dataclasses.replace(tok, **kw)


CASES = {
    "lines: bool vertices": (lambda t: raster.line_crossings(V > 0, F, G, 0), TypeError, "`vertices`"),
    "lines: complex vertices": (lambda t: raster.line_crossings(V + 0j, F, G, 0), TypeError, "`vertices`"),
    "lines: bool faces": (lambda t: raster.line_crossings(V, F > 0, G, 0), TypeError, "`faces`"),
    "lines: bool coordinates": (
        lambda t: raster.line_crossings(V, F, G, 0, lines=([True, False], [0.0])), TypeError, "real numbers"),
    "lines: complex coordinates": (
        lambda t: raster.line_crossings(V, F, G, 0, lines=([0j, 1j], [0.0])), TypeError, "real numbers"),
    "lines: 2-D coordinates": (
        lambda t: raster.line_crossings(V, F, G, 0, lines=(np.zeros((2, 2)), [0.0])), ValueError, "1-D"),
    "lines: 1e300 coordinate": (
        lambda t: raster.line_crossings(V, F, G, 0, lines=([1e300], [0.0])), ValueError, "1e\\+75"),
    "lines: tiny coordinate": (
        lambda t: raster.line_crossings(V, F, G, 0, lines=([1e-60], [0.0])), ValueError, "line_crossings: line"),
    "lines: threads 0": (lambda t: raster.line_crossings(V, F, G, 0, threads=0), ValueError, "`threads`"),
    "lines: too many": (
        lambda t: raster.line_crossings(V, F, voxax.Grid.cube(200_000), 0, lines="nodes"), MemoryError, "GiB"),
    "encode: bool vertices": (lambda t: fc.encode(V > 0, F, G), TypeError, "`vertices`"),
    "encode: complex vertices": (lambda t: fc.encode(V + 0j, F, G), TypeError, "`vertices`"),
    "encode: bool faces": (lambda t: fc.encode(V, F > 0, G), TypeError, "`faces`"),
    "encode: no grid": (lambda t: fc.encode(V, F), TypeError, "`grid`"),
    "encode: anchors": (lambda t: fc.encode(V, F, G, anchors_per_cell=2), ValueError, "`anchors_per_cell`"),
    "encode: threads": (lambda t: fc.encode(V, F, G, threads=-1), ValueError, "`threads`"),
    "encode: grid too large": (lambda t: fc.encode(V, F, voxax.Grid.cube(20_000)), MemoryError, "GiB"),
    "pieces: bool vertices": (lambda t: fc.pieces(V > 0, F, G), TypeError, "`vertices`"),
    "decode: float signs": (lambda t: fc.decode(_edit(t, edge_signs=t.edge_signs * 0.5)), TypeError, "edge_signs"),
    "decode: bool signs": (lambda t: fc.decode(_edit(t, edge_signs=t.edge_signs != 0)), TypeError, "edge_signs"),
    "decode: signs 300": (
        lambda t: fc.decode(_edit(t, edge_signs=t.edge_signs.astype(np.int64) * 300)), ValueError, "-127, 127"),
    "decode: signs -128": (
        lambda t: fc.decode(_edit(t, edge_signs=np.where(t.edge_signs != 0, -128, 0).astype(np.int8))),
        ValueError, "-127, 127"),
    "decode: offsets 1e300": (lambda t: fc.decode(_edit(t, offsets=t.offsets * 0 + 1e300)), ValueError, "offsets"),
    "decode: offsets outside": (lambda t: fc.decode(_edit(t, offsets=t.offsets * 0 + 0.7)), ValueError, "offsets"),
    "decode: NaN offsets": (lambda t: fc.decode(_edit(t, offsets=t.offsets * np.nan)), ValueError, "offsets"),
    "decode: complex offsets": (lambda t: fc.decode(_edit(t, offsets=t.offsets + 0j)), TypeError, "offsets"),
    "decode: NaN normals": (lambda t: fc.decode(_edit(t, normals=t.normals * np.nan)), ValueError, "normals"),
    "decode: float index": (lambda t: fc.decode(_edit(t, index=t.index.astype(float))), TypeError, "index"),
    "decode: index out of range": (lambda t: fc.decode(_edit(t, index=t.index + G.size)), ValueError, "index"),
    "decode: unsorted": (lambda t: fc.decode(_edit(t, index=t.index[::-1].copy())), ValueError, "sorted"),
    "decode: short normals": (lambda t: fc.decode(_edit(t, normals=t.normals[:3])), ValueError, "shape"),
    "decode: not a grid": (lambda t: fc.decode(_edit(t, grid="x")), TypeError, "`grid`"),
    "decode: not tokens": (lambda t: fc.decode(5), TypeError, "`tokens`"),
    "decode: threads": (lambda t: fc.decode(t, threads=0), ValueError, "`threads`"),
    "from_array: offsets 1e300": (
        lambda t: fc.Tokens.from_array(np.concatenate([[[0.0]], np.full((1, 3), 1e300), np.zeros((1, 15))], 1), G),
        ValueError, "cells"),
    "roundtrip: samples 0": (lambda t: fc.roundtrip(CUBE, 8, samples=0, progress=False), ValueError, "`samples`"),
    "roundtrip: key": (lambda t: fc.roundtrip(CUBE, 8, key=-1, progress=False), ValueError, "`key`"),
    "edge_topology: bool faces": (lambda t: fc.edge_topology(V, F > 0), TypeError, "`faces`"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_input_is_refused(name, tok):
    call, error, match = CASES[name]
    ns = "raster.line_crossings" if name.startswith("lines") else "fc."
    with pytest.raises(error, match=match) as info:
        call(tok)
    assert str(info.value).startswith("voxax." + ns), str(info.value)


def test_refused_edits_leave_the_tokens_alone(tok):
    before = tok.to_array()
    with pytest.raises(ValueError):
        fc.decode(_edit(tok, offsets=tok.offsets * 0 + 0.7))
    assert np.array_equal(tok.to_array(), before)

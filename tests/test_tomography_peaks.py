"""Peaks placed between pixel centres: the three-point (parabola) estimator of a sampled maximum."""

import numpy as np
import pytest

from vehicle.tomography.imaging import find_peaks, subpixel_offset
from vehicle.tomography.weights import LAMBDA, Grid, default_cell

GRID = Grid((0.0, 0.0, 6.4, 6.4), 0.2)


def blob(centre, width=0.4, grid=GRID):
    """A smooth blob sampled at the pixel centres (rows south to north, as the images)."""
    xy = grid.centres() - np.asarray(centre)
    return np.exp(-0.5 * (xy ** 2).sum(axis=1) / width ** 2).reshape(grid.shape)


@pytest.mark.parametrize("centre", [(2.37, 3.92), (4.01, 1.69), (3.19, 3.31)])
def test_a_peak_between_pixel_centres_is_placed_within_3_cm(centre):
    peak = find_peaks(blob(centre), GRID, 1, 0.5)[0]
    pixel = GRID.centres()[np.argmax(blob(centre))]
    assert np.linalg.norm(pixel - centre) > 0.07  # the pixel centre alone is this far off
    assert np.hypot(peak["x"] - centre[0], peak["y"] - centre[1]) < 0.03
    assert peak["value"] == round(float(blob(centre).max()), 4)  # the value stays the pixel's own


def test_the_parabola_through_three_samples_peaks_where_it_should():
    # y = 5 - (x - 0.3)^2 at x = -1, 0, 1: the vertex is at 0.3
    assert subpixel_offset(*(np.array([5 - (x - 0.3) ** 2]) for x in (-1, 0, 1)))[0] == pytest.approx(0.3)
    # no bend down (flat, rising) or a neighbour outside the image: no shift; never more than half a pixel
    assert subpixel_offset(np.array([1.0]), np.array([1.0]), np.array([1.0]))[0] == 0
    assert subpixel_offset(np.array([np.nan]), np.array([2.0]), np.array([1.0]))[0] == 0
    assert subpixel_offset(np.array([2.0]), np.array([2.0]), np.array([0.0]))[0] == pytest.approx(-0.5)


def test_a_peak_on_the_edge_of_the_image_stays_inside_the_bounds():
    # the blob's centre is west of the image: its maximum is the west column's pixel; there is no pixel beyond
    # it to fit, so the peak stays at that pixel's centre across, and is placed between centres along the edge
    peak = find_peaks(blob((-0.3, 2.45)), GRID, 1, 0.5)[0]
    assert peak["x"] == pytest.approx(0.1)
    assert abs(peak["y"] - 2.45) < 0.03
    # bounds that are not a whole number of cells: the east column's centre (6.3) lies beyond them (6.25)
    grid = Grid((0.0, 0.0, 6.25, 6.4), 0.2)
    peak = find_peaks(blob((6.8, 2.45), grid=grid), grid, 1, 0.5)[0]
    assert peak["x"] == pytest.approx(6.25)


def test_several_peaks_keep_their_order_and_each_its_own_position():
    image = blob((1.33, 1.27)) + 0.8 * blob((4.46, 4.58))
    peaks = find_peaks(image, GRID, 2, 0.5)
    assert [p["value"] for p in peaks] == sorted((p["value"] for p in peaks), reverse=True)
    for peak, centre in zip(peaks, [(1.33, 1.27), (4.46, 4.58)], strict=True):
        assert np.hypot(peak["x"] - centre[0], peak["y"] - centre[1]) < 0.03


def test_the_default_cell_is_a_tidy_number_fine_enough_for_a_person_and_the_ellipses():
    assert repr(default_cell((0.0, 0.0, 8.128, 7.8232))) == "0.15"  # the JSON's "cell", not 0.15000000000000002
    half_width = np.sqrt(1.0 * LAMBDA / 2 + LAMBDA ** 2 / 4)  # the ellipse of a 1 m link, at its middle
    for side in (2.0, 6.4, 8.128, 10.0):
        cell = default_cell((0.0, 0.0, side, side))
        assert 0.1 <= cell <= min(0.2, half_width) and cell == round(cell, 2)

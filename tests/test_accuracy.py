"""Issue 13: hard objects. Symmetry reports against the procedural objects' known symmetries, and
tracking bounds on short rendered recordings of the objects suite."""

import numpy as np
import pytest

from evservo import _evcore, models
from evservo.bench import objects
from evservo.sim.record import start_pose
from evservo.tracking import Tracker

CAM = _evcore.Camera.imx636()


def _about(symmetries, axis):
    """The symmetries whose axis is ``axis`` (either sign)."""
    return [s for s in symmetries if abs(np.dot(s.axis_o, axis)) > 0.99]


@pytest.mark.parametrize(
    ("name", "period_deg"),
    [("cylinder", 0.0), ("checker-can", 22.5), ("can", None)],
)
def test_symmetry_about_the_can_axis_is_found_by_rendering(name, period_deg):
    found = _about(models.symmetries(name), (0.0, 1.0, 0.0))
    known = _about(models.builtin_symmetries(name), (0.0, 1.0, 0.0))
    if period_deg is None:
        # The irregular label breaks every turn about the axis.
        assert found == [] and known == []
    else:
        assert [s.period_deg for s in found] == [period_deg] == [s.period_deg for s in known]


def test_box_print_breaks_its_geometric_symmetry():
    # A bare box has three 180° symmetries; its print has none.
    assert models.symmetries("box") == []


def _edge_start(name):
    mesh = models.to_core_mesh(models.load_object(name))
    return objects.start_pose(objects.Case(name, 0.6, "edge"), CAM, mesh.bounding_radius)


def test_a_view_without_the_handle_turns_freely_about_the_mug_axis():
    # The suite's mug-z0.6-edge start: the handle lies beyond the right border. Every solver turned
    # 15-20° about the mug's axis there; the view, not the mug, has that symmetry.
    T = _edge_start("mug")
    spin = _about(models.symmetries("mug", CAM, T), (0.0, 1.0, 0.0))
    assert [s.period_deg for s in spin] == [0.0], spin
    # Found on the body's axis (x = -17 mm in the mug's frame, centred on its bounding box), not the
    # whole mug's centroid, which leans towards the handle.
    assert abs(spin[0].centre_o[0] + 0.017) < 2e-3 and abs(spin[0].centre_o[2]) < 2e-3, spin
    axes = objects.unobservable_axes(objects.Case("mug", 0.6, "edge"), CAM, T)
    assert [why for _, why in axes] == ["symmetry of the view"]
    # In full view the handle shows: no turn about the axis leaves the edges alone.
    assert _about(models.symmetries("mug", CAM, start_pose(0.6)), (0.0, 1.0, 0.0)) == []
    assert objects.unobservable_axes(objects.Case("mug", 0.6, "full"), CAM, start_pose(0.6)) == []


def test_a_partial_view_of_the_labelled_can_keeps_it_observable():
    # The label breaks the can's spin in the part in view as well.
    assert _about(models.symmetries("can", CAM, _edge_start("can")), (0.0, 1.0, 0.0)) == []


def test_observable_rotation_error_leaves_out_the_spin_about_a_symmetry_axis():
    from scipy.spatial.transform import Rotation

    truth = start_pose(0.6)
    axis = np.array([0.0, 1.0, 0.0])
    est = truth.copy()
    # 40° about the object's own axis (unobservable), then a 3° tilt of that axis.
    est[:3, :3] = truth[:3, :3] @ Rotation.from_rotvec(np.deg2rad(40.0) * axis).as_matrix()
    on_axis = truth[:3, :3] @ axis
    tilt = np.cross(on_axis, (0.0, 0.0, 1.0))
    est[:3, :3] = Rotation.from_rotvec(np.deg2rad(3.0) * tilt / np.linalg.norm(tilt)).as_matrix() @ est[:3, :3]
    whole = np.rad2deg(objects.observable_rotation_error_rad(est, truth, []))
    observable = np.rad2deg(objects.observable_rotation_error_rad(est, truth, [axis]))
    assert whole > 39.0 and abs(observable - 3.0) < 0.05, (whole, observable)


def test_tracker_reports_unobservable_axes_and_ambiguities():
    T = start_pose(0.6)
    plain = Tracker(CAM, "cylinder", T)
    assert plain.unobservable_axes == [(0.0, 1.0, 0.0)]
    assert {s.period_deg for s in plain.ambiguities} == {180.0}
    checker = Tracker(CAM, "checker-can", T)
    assert checker.unobservable_axes == [] and 22.5 in {s.period_deg for s in checker.ambiguities}
    labelled = Tracker(CAM, "can", T)
    assert labelled.unobservable_axes == [] and labelled.ambiguities == []
    with pytest.raises(ValueError, match="held_axes"):
        _evcore.Tracker(CAM, labelled.points_o, T, held_axes=np.zeros((1, 5)))


@pytest.fixture(scope="module")
def can_rows():
    """The labelled can at Z = 0.6 m in full view, 0.3 s rendered, tracked by all three solvers."""
    case = objects.Case("can", 0.6, "full", duration_s=0.3)
    events, gt_t, gt_T = objects.render_case(case, CAM)
    return {s: objects.track_case(case, CAM, events, gt_t, gt_T, s) for s in ("edft+", "edopts", "edft")}


def test_labelled_can_meets_the_accuracy_target(can_rows):
    row = can_rows["edft+"]
    assert row["pos_rms_mm"] <= 5.0 and row["rot_rms_deg"] <= 2.0, row
    assert row["lost_fraction"] == 0.0 and row["visible_fraction"] == 1.0


def test_lm_is_never_much_worse_than_the_search_on_rotation(can_rows):
    for solver in ("edft+", "edft"):
        assert can_rows[solver]["rot_rms_deg"] <= can_rows["edopts"]["rot_rms_deg"] + 0.5, can_rows


@pytest.mark.parametrize("extent_px", [30.0, 40.0, 60.0, 100.0, 159.0, 200.0, 900.0])
def test_field_scale_keeps_the_coarsest_level_readable(extent_px):
    from evservo.tracking import field_scale

    levels, tau = field_scale(extent_px)
    assert 1 <= levels <= 3
    # The object spans 40 px or more at the coarsest level, unless it is smaller than that already.
    assert extent_px / 2 ** (levels - 1) >= min(40.0, extent_px)
    # One level deeper would shrink it below that: no level is dropped needlessly.
    assert levels == 3 or extent_px / 2**levels < 40.0
    assert 4.0 <= tau <= 10.0 and (tau <= extent_px / 8.0 or tau == 4.0)
    if extent_px >= 160:
        assert (levels, tau) == (3, 10.0)  # the paper's settings for objects of ordinary size


@pytest.fixture(scope="module")
def can_edge_rows():
    """The labelled can at Z = 0.6 m with a third of it out of view (right border), 0.2 s."""
    case = objects.Case("can", 0.6, "edge", duration_s=0.2)
    events, gt_t, gt_T = objects.render_case(case, CAM)
    return {s: objects.track_case(case, CAM, events, gt_t, gt_T, s) for s in ("edft+", "edopts")}


def test_partly_out_of_view_can_meets_the_target_and_lm_does_not_drift(can_edge_rows):
    row = can_edge_rows["edft+"]
    assert row["visible_fraction"] < 0.99  # the case is really partial
    assert row["pos_rms_mm"] <= 5.0 and row["rot_rms_deg"] <= 2.0, row
    assert row["rot_rms_deg"] <= can_edge_rows["edopts"]["rot_rms_deg"] + 0.5, can_edge_rows


@pytest.fixture(scope="module")
def box_occluded_rows():
    """The printed box at Z = 1.2 m with 30 % of it behind a plate, 0.1 s."""
    case = objects.Case("box", 1.2, "occluded", duration_s=0.1)
    events, gt_t, gt_T = objects.render_case(case, CAM)
    return {s: objects.track_case(case, CAM, events, gt_t, gt_T, s) for s in ("edft+", "edopts")}


def test_occluded_far_box_is_not_pulled_off_by_the_coarse_levels(box_occluded_rows):
    # With the old judge of the pyramid (Eq. 1, which charges hidden points τ wherever they are)
    # the ¼ level jumped 85 mm / 10° after 24 ms and stayed there (110 mm RMS).
    row = box_occluded_rows["edft+"]
    assert row["pos_rms_mm"] <= 12.0, box_occluded_rows  # 1 % of the distance
    assert row["rot_rms_deg"] <= box_occluded_rows["edopts"]["rot_rms_deg"] + 0.5, box_occluded_rows


@pytest.fixture(scope="module")
def box_far_edge_rows():
    """The printed box at Z = 1.2 m (about 100 px across) partly out of view, 0.5 s."""
    case = objects.Case("box", 1.2, "edge")
    events, gt_t, gt_T = objects.render_case(case, CAM)
    return {s: objects.track_case(case, CAM, events, gt_t, gt_T, s) for s in ("edft+", "edopts")}


def test_far_box_at_the_border_does_not_ratchet_on_noise_level_search_wins(box_far_edge_rows):
    # One search candidate is a 1.5° out-of-plane turn here. Taking every candidate that beat the null
    # by 0.4–1.7 % of the cost while the field filled ratcheted EDFT⁺ to 60 mm / 13°, along directions
    # the LM steps saw too weakly (outline cut by the border) to undo; a step now moves only on a win of
    # 3 standard errors of the per-point gains (search_min_t).
    row = box_far_edge_rows["edft+"]
    assert row["pos_rms_mm"] <= 12.0, box_far_edge_rows  # 1 % of the distance
    assert row["rot_rms_deg"] <= 2.0, box_far_edge_rows
    assert row["rot_rms_deg"] <= box_far_edge_rows["edopts"]["rot_rms_deg"] + 0.5, box_far_edge_rows


@pytest.fixture(scope="module")
def part_far_edge_rows():
    """The matte L-bracket at Z = 1.2 m partly out of view, 0.1 s."""
    case = objects.Case("part", 1.2, "edge", duration_s=0.1)
    events, gt_t, gt_T = objects.render_case(case, CAM)
    return {s: objects.track_case(case, CAM, events, gt_t, gt_T, s) for s in ("edft+", "edopts", "edft")}


def test_far_part_at_the_border_is_not_slid_off_by_search_steps_on_a_filling_field(part_far_edge_rows):
    # In the first millisecond (73 fired pixels for 844 model points) four search steps each won on
    # Eq. (1) with t of 6-10 by sliding points far from every event towards the few that fired, while
    # losing in LM's robust loss; LM followed them into a wrong basin (about 30 mm / 30° over this
    # 0.1 s, LM alone 7.6 mm / 1.5°). The test of a search step now counts gains in the robust loss.
    rows = part_far_edge_rows
    row = rows["edft+"]
    assert row["visible_fraction"] < 0.99  # the case is really partial
    assert row["pos_rms_mm"] <= 12.0, rows  # 1 % of the distance
    assert row["rot_rms_deg"] <= 2.0, rows
    # The cascade is not worse than its LM alone, nor than the search alone.
    assert row["rot_rms_deg"] <= rows["edft"]["rot_rms_deg"] + 0.5, rows
    assert row["rot_rms_deg"] <= rows["edopts"]["rot_rms_deg"] + 0.5, rows


def test_search_min_t_is_checked():
    T = objects.start_pose(objects.Case("box", 0.6, "full"), CAM, 0.15)
    for bad in (-1.0, float("nan")):
        with pytest.raises(ValueError, match="search_min_t"):
            Tracker(CAM, "box", T, search_min_t=bad)

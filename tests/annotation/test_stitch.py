import numpy as np
import pytest

from annotate_rgbd.annotation.model import Annotation
from annotate_rgbd.config.annotation import MatchConfig
from annotate_rgbd.errors import InputError
from annotate_rgbd.annotation.parts import frame_owners, place_parts
from annotate_rgbd.io.sequence import FrameList
from annotate_rgbd.annotation.stitch import AUTOMATIC, FIRST_PART, MANUAL, NEW, PartTracks, assign_planes, match_tracks, track_ious

RGB = FrameList(np.arange(100) / 30.0, tuple(f"rgb/{i}.png" for i in range(100)))


def video(name, n_frames, step=1):
    return Annotation(path=f"/x/{name}", format="video", tracks=[], frames=list(range(0, n_frames, step)))


def test_track_ious_counts_pixels_of_every_pair():
    a = np.array([[1, 1, 0], [2, 2, 0]])
    b = np.array([[1, 0, 0], [2, 2, 2]])
    inter, union = track_ious(a, b, 2, 2)
    assert inter.tolist() == [[1, 0], [0, 2]]
    assert union.tolist() == [[2, 5], [3, 3]]


def test_match_tracks_is_optimal_not_greedy():
    # Greedy on the best pair (0.9) would leave 0.1; the optimum pairs 0.8 + 0.8.
    iou = np.array([[0.9, 0.8], [0.8, 0.1]])
    assert match_tracks(iou, 0.5) == [(0, 1, 0.8), (1, 0, 0.8)]
    assert match_tracks(np.array([[0.4]]), 0.5) == []
    assert match_tracks(np.zeros((0, 3)), 0.5) == []


def parts3():
    return [
        PartTracks("0-40.xml", [0, 1, 2], ["wall", "floor", "table"]),
        PartTracks("38-80.xml", [5, 3, 9], ["floor", "wall", "chair"]),
        PartTracks("78-99.xml", [0, 1], ["wall", "table"]),
    ]


def ious3():
    first = np.zeros((3, 3))
    first[0, 1], first[1, 0] = 0.9, 0.8  # wall=3, floor=5; table left view, chair new
    second = np.zeros((3, 2))
    second[1, 0] = 0.7  # wall again; part 3's table (track 1) matches nothing
    return [first, second]


def test_assign_planes_automatic_matching_over_three_parts():
    tracks = assign_planes(parts3(), ious3(), [], 0.5)
    got = {(t.part, t.track): (t.plane, t.how) for t in tracks}
    assert got == {
        ("0-40.xml", 0): (1, FIRST_PART),
        ("0-40.xml", 1): (2, FIRST_PART),
        ("0-40.xml", 2): (3, FIRST_PART),
        ("38-80.xml", 3): (1, AUTOMATIC),
        ("38-80.xml", 5): (2, AUTOMATIC),
        ("38-80.xml", 9): (4, NEW),
        ("78-99.xml", 0): (1, AUTOMATIC),
        ("78-99.xml", 1): (5, NEW),  # the table came back: a new plane unless fixed by hand
    }
    auto = next(t for t in tracks if (t.part, t.track) == ("38-80.xml", 3))
    assert (auto.iou, auto.matched_part, auto.matched_track) == (0.9, "0-40.xml", 0)


def test_manual_entries_override_and_reconnect():
    manual = [
        MatchConfig(part="78-99.xml", track=1, with_part="0-40.xml", with_track=2),  # the returning table
        MatchConfig(part="38-80.xml", track=5, new=True),  # wrong automatic match undone
        MatchConfig(part="38-80.xml", track=9, plane=2),  # ... and given to the right track
    ]
    got = {(t.part, t.track): (t.plane, t.how) for t in assign_planes(parts3(), ious3(), manual, 0.5)}
    assert got[("38-80.xml", 5)] == (4, MANUAL)
    assert got[("38-80.xml", 9)] == (2, MANUAL)
    assert got[("38-80.xml", 3)] == (1, AUTOMATIC)
    assert got[("78-99.xml", 1)] == (3, MANUAL)


def test_a_pinned_plane_is_not_matched_automatically_again():
    manual = [MatchConfig(part="38-80.xml", track=9, plane=1)]
    got = {(t.part, t.track): (t.plane, t.how) for t in assign_planes(parts3(), ious3(), manual, 0.5)}
    assert got[("38-80.xml", 9)] == (1, MANUAL)
    assert got[("38-80.xml", 3)] == (4, NEW)  # plane 1 is taken by the manual entry


@pytest.mark.parametrize(
    "entry, message",
    [
        (MatchConfig(part="nope.xml", track=1, plane=1), "unknown part 'nope.xml'"),
        (MatchConfig(part="38-80.xml", track=4, plane=1), "38-80.xml has no track 4"),
        (MatchConfig(part="38-80.xml", track=3, with_part="0-40.xml", with_track=7), "0-40.xml has no track 7"),
        (MatchConfig(part="38-80.xml", track=3, plane=9), "no earlier part has plane 9"),
        (MatchConfig(part="38-80.xml", track=3), "give exactly one of"),
        (MatchConfig(part="38-80.xml", track=3, plane=1, new=True), "give exactly one of"),
        (MatchConfig(part="38-80.xml", track=3, with_part="38-80.xml", with_track=5), "both tracks are in"),
    ],
)
def test_bad_manual_entries_are_errors(entry, message):
    with pytest.raises(InputError, match=message):
        assign_planes(parts3(), ious3(), [entry], 0.5, "scene.toml")


def test_parts_are_placed_by_file_name_explicit_offset_and_ordered():
    parts, warnings = place_parts([video("50-79.xml", 30), video("b.xml", 55)], RGB, {"b.xml": 0})
    assert [(p.name, p.first, p.last, p.offset_source) for p in parts] == [
        ("b.xml", 0, 54, "explicit"),
        ("50-79.xml", 50, 79, "file name"),
    ]
    owners = frame_owners(parts)
    assert owners[49] == 0 and owners[50] == 1 and owners[54] == 1  # the later part wins from its start
    assert warnings == []


def test_a_single_export_needs_no_offset():
    parts, warnings = place_parts([video("annotations.xml", 100, step=3)], RGB, {})
    assert parts[0].first == 0 and parts[0].offset_source == "single export" and warnings == []
    # One that spans a tenth of the frames (another, shorter sequence's, or a job): said.
    parts, warnings = place_parts([video("annotations.xml", 10)], RGB, {})
    assert parts[0].first == 0 and warnings == [
        "/x/annotations.xml: its frames are RGB frames 0-9 of the sequence's 100: the others get no mask (an export "
        "of another sequence? a part of this one: give its offset, --part annotations.xml:OFFSET)"]
    # One whose task starts at frame 10 (CVAT's start_frame) is already placed: no offset to give.
    started = Annotation(path="/x/annotations.xml", format="video", tracks=[], frames=list(range(10, 20, 3)))
    parts, warnings = place_parts([started], RGB, {})
    assert (parts[0].first, parts[0].last) == (10, 19) and warnings == [
        "/x/annotations.xml: its frames are RGB frames 10-19 of the sequence's 100 (its task starts at frame 10): "
        "the others get no mask"]


@pytest.mark.parametrize(
    "annotations, offsets, message",
    [
        ([video("a.xml", 10), video("b.xml", 10)], {"b.xml": 5}, "cannot tell where this part starts.*--part a.xml:OFFSET"),
        ([video("0-20.xml", 10)], {}, "file name says RGB frames 0-20"),
        ([video("0-49.xml", 50), video("10-29.xml", 20)], {}, "lie within 0-49.xml"),
        ([video("a.xml", 50), video("b.xml", 50)], {"a.xml": 0, "b.xml": 60}, "part does not fit in the sequence"),
        ([video("a.xml", 5)], {"c.xml": 3}, "not among the annotation parts"),
    ],
)
def test_parts_that_cannot_be_placed_are_errors(annotations, offsets, message):
    with pytest.raises(InputError, match=message):
        place_parts(annotations, RGB, offsets)


def test_a_job_export_named_by_its_first_frame_is_placed_there():
    # A job export's frames are task-absolute (here 7..16); its file name gives RGB index 7.
    job = Annotation(path="/x/7-16.xml", format="video", tracks=[], frames=list(range(7, 17)))
    parts, _ = place_parts([video("0-9.xml", 10), job], RGB, {})
    assert [(p.name, p.first, p.last) for p in parts] == [("0-9.xml", 0, 9), ("7-16.xml", 7, 16)]


# --- plane ids carried by the tracks (the plane_id attribute of propose and export-cvat) ---------


def carrying(track_id, label, frames, plane_id=None):
    """A track visible on ``frames``, carrying ``plane_id`` (text) when given."""
    from annotate_rgbd.annotation.model import PLANE_ID, Shape, Track

    square = Shape("polygon", np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0]]))
    return Track(track_id, label, dict.fromkeys(frames, square),
                 attributes={} if plane_id is None else {PLANE_ID: plane_id})


def test_carried_plane_ids_keep_their_ids_and_new_tracks_get_fresh_ones():
    from annotate_rgbd.annotation.stitch import CARRIED, carried_plane_ids

    tracks = [carrying(0, "wall", [0, 1], "7"), carrying(1, "new", [0, 1]), carrying(2, "floor", [0, 1], "2"),
              carrying(3, "desk", [1, 2])]
    ids, problems = carried_plane_ids(tracks, "round2.xml")
    assert ids == [7, None, 2, None] and problems == []
    part = PartTracks("round2.xml", [0, 1, 2, 3], ["wall", "new", "floor", "desk"], tuple(ids))
    got = {t.track: (t.plane, t.how) for t in assign_planes([part], [], [], 0.5)}
    # The carried ids stay; the others start above the largest carried one (never 1, 3..6: planes
    # of the earlier round that no track shows now), in track order.
    assert got == {0: (7, CARRIED), 1: (8, FIRST_PART), 2: (2, CARRIED), 3: (9, FIRST_PART)}


def test_carried_ids_that_cannot_be_used():
    from annotate_rgbd.annotation.stitch import carried_plane_ids

    tracks = [carrying(0, "a", [0, 1], "3"), carrying(1, "b", [2, 3], "3"),  # split track: one plane
              carrying(2, "c", [1, 5], "3"),  # a copy seen with track 0 on frame 1: not plane 3
              carrying(3, "d", [0], "x1"), carrying(4, "e", [0], "0"), carrying(5, "f", [0], "70000"),
              carrying(6, "g", [0], "")]
    ids, problems = carried_plane_ids(tracks, "p.xml")
    assert ids == [3, 3, None, None, None, None, None]
    assert len(problems) == 4
    assert "tracks 0 and 2 both carry plane_id 3 and are both visible on frame 1: track 2" in problems[0]
    assert all("is no plane id (1 to 65535)" in line for line in problems[1:])


def test_carried_ids_across_parts_take_precedence_over_matching():
    # Part 2's track 3 carries plane 1 (the wall) while overlapping part 1's floor best: the
    # attribute wins, and the floor's automatic match goes to the track that overlaps it next.
    parts = [PartTracks("0-40.xml", [0, 1], ["wall", "floor"], (1, 2)),
             PartTracks("38-80.xml", [3, 4, 5], ["wall", "floor", "chair"], (1, None, None))]
    iou = np.array([[0.0, 0.0, 0.0], [0.9, 0.6, 0.0]])
    got = {(t.part, t.track): (t.plane, t.how) for t in assign_planes(parts, [iou], [], 0.5)}
    assert got[("38-80.xml", 3)] == (1, "plane_id")
    assert got[("38-80.xml", 4)] == (2, AUTOMATIC)
    assert got[("38-80.xml", 5)] == (3, NEW)


def test_a_manual_entry_beats_a_carried_id():
    parts = [PartTracks("0-40.xml", [0, 1], ["wall", "floor"], (4, 9)),
             PartTracks("38-80.xml", [3], ["wall"], (9,))]
    manual = [MatchConfig(part="38-80.xml", track=3, plane=4)]
    got = {(t.part, t.track): (t.plane, t.how) for t in assign_planes(parts, [np.zeros((2, 1))], manual, 0.5)}
    assert got[("38-80.xml", 3)] == (4, MANUAL)
    with pytest.raises(InputError, match="no earlier part has plane 5"):
        assign_planes(parts, [np.zeros((2, 1))], [MatchConfig(part="38-80.xml", track=3, plane=5)], 0.5)

"""3D tracks with stable ids, a lifecycle and Kalman filters (moving straight, or falling).

Association is done in the images, where skew cannot bias it: each track predicts where its
object is in each eye at that eye's own capture instant (its filter's prediction projected
into that eye; before the filter runs, its last centroid moved along that eye's image
velocity, or the line through its first two positions projected), and each stereo detection
is assigned to the track it is nearest to in both eyes at once, globally (Hungarian
algorithm), within a gate: confirmed tracks first, then tentative ones among the detections
left. A track with one observation
has no velocity yet; its gate is how far an object at ``max_speed_mps`` can move in the image at
its depth (its disparity gives the pixels per metre), so an object as fast as a thrown ball is
followed from its second frame. A detection that a live object's prediction explains in both
eyes (a piece of it) starts no track; one that two confirmed tracks fall into (two objects
crossing, one hiding the other) updates neither: both coast until they part; unless one is
clearly in front (nearer by more than ``merge_depth_m``), whole in the blob, the other joining
it on one side: it is measured by its outline's other side, like an object cut by the image's
edge. A detection that would start a track but came out, in both eyes, of the blob that hid a
confirmed track in the last pair is that track's object reappearing, wherever its prediction
went (a person seen for three frames before a crossing has a velocity that is a guess). A
confirmed track given a blob under ``SHRINK`` of its last outline's size, across and down, in
an eye sees a piece of its object (a head above the shoulder of one in front): its filter
predicts, and the last whole outline is kept to tell the next blob by. A confirmed track's
detection beyond its gate whose boxes and the track's predicted ones hold one another with
their ends shared (:func:`boxes.recuts`), in both eyes and alone there, is its object
re-segmented (a ball's long shadow taken in or left out): its box grown by more than
``RECUT_GROWN`` in area, the track counts as unseen and coasts through it for up to
``max_coast_s`` (then takes it: the object did grow); otherwise it moves onto it with its
velocity kept.

The filter's measurement is each observation's triangulated position with its covariance, so
depth noise growing as Z^2 (eq. 12) is weighted correctly. It starts at a track's second
observation from the two positions, whose difference is its first velocity (eq. 21 over one
frame); an observation far outside the filter's prediction widens the prediction until it
is not (a fading memory). Beside the constant-velocity filter a free-fall one runs (gravity
``gravity_mps2``), and the track reports whichever has explained its recent positions better:
a thrown ball is followed along its arc. Velocity, speed and heading come from the filter
(eq. 22, 23 on its velocity); the paper's eq. 21 finite difference over ``time_base_s`` is kept
beside them as the raw velocity. A velocity is valid once the track is confirmed and the
speed's own sigma is small (``valid_speed_sigma_mps`` or ``valid_speed_sigma_rel`` of the
speed, whichever is larger); its heading is valid once, besides, the velocity's sigma across
its direction on the ground is within the same bound and the heading's sigma within
``VALID_HEADING_SIGMA_DEG``: a track's first estimates often know the speed long before the
direction (two observations of a ball across the view, each a few cm off in depth, give its
speed to 2 % and its heading to 12 deg), and an object slow on the ground, or falling, may
have a speed known to 0.1 m/s and no direction at all.

Lifecycle: ``tentative`` until ``confirm_hits`` observations and a running filter (two
observations no faster than ``max_speed_mps`` apart), then ``confirmed``; a tentative track
given a blob of another width (beyond ``REGROWN``: the object merged with its long shadow)
holds it aside for a pair, and begins again from the second such pair in a row; a confirmed track
seen moving that has not moved for ``still_after_s`` is ``stationary`` (held out of the
background for ``hold_still_s``, so it stays seen and keeps its id when it moves on); a confirmed
track not seen in a pair is ``coasting`` (predicted) until ``max_coast_s`` has passed (longer
while hidden, see :meth:`Tracker.update`; sooner if its velocity is a guess its prediction
takes out of the view), then it ends. A tentative track ends at its first miss, except that
one seen once waits one pair (still ``tentative``): an object entering the view is small,
and one eye may miss it once.
A confirmed track found to be a piece of another's object (at one depth, moving with it: a
box a robot pushes) is kept as a member of that object, unpublished and not ended, for up to
``max_member_s``: a blob that would start a track, coming out of that object's blobs, takes
the member's id back (the box the robot leaves), so an id is never ended and then used again.
Ids are never reused. All times are seconds computed from timestamps, never frame counts.

The data are in :mod:`stereod.tracking.types`, association in
:mod:`stereod.tracking.association`, one track's filters and lifecycle in
:mod:`stereod.tracking.track`; :class:`Tracker` here runs them pair by pair.
"""

from __future__ import annotations

import math

import numpy as np

from stereod.tracking import kalman, measure
from stereod.tracking.association import Association, Projector, predict_px
from stereod.tracking.boxes import inside, overlaps, union
from stereod.tracking.track import Track, behind
from stereod.tracking.types import (
    Detection,
    EyeHistory,
    Observation,
    TrackerParams,
    TrackState,
)


class Tracker(Association):
    """Per pair: :meth:`associate` detections in the images, then :meth:`update` with the
    observations triangulated from them (after skew compensation) and the same assignment."""

    def __init__(
        self,
        params: TrackerParams,
        project: Projector | None = None,
        view_px: tuple[int, int] | None = None,
    ) -> None:
        """``project`` maps a rig-frame point (m) to rectified px in one eye; with it,
        a track whose filter runs is looked for where its 3D prediction projects (which
        follows perspective: an object coming at the camera speeds up in the image), else
        where its image velocity leads. ``view_px``: the images' width and height (px)."""
        self.params = params
        self._project = project
        self._merging: dict[int, int] = {}
        """Tracks the last :meth:`associate` found to be pieces of another's object (absorbed
        id -> keeper id): they become members of it in :meth:`update` once the keeper is seen."""
        self._members: dict[int, Track] = {}
        """Tracks taken into another's object (id -> track, its ``member_of`` the keeper's id):
        not published and not ended, for up to ``max_member_s``; one comes back when a blob that
        would start a track comes out of that object (:meth:`associate`)."""
        self._shared: set[int] = set()
        """Detections the last :meth:`associate` found two or more confirmed tracks' predictions
        in (index): what they show of any one object is blended with another's."""
        self._fronts: dict[int, tuple[bool, float]] = {}
        """Detections the last :meth:`associate` gave to the nearer of two objects in one blob
        (index -> whether the other joins it on its right, and the other's predicted disparity,
        px): each is measured by its outline's other side in :meth:`update`
        (:func:`stereod.tracking.measure.by_edge`)."""
        self._recut: set[tuple[int, int]] = set()
        """(Detection index, track id) pairs the last :meth:`associate` found to be that
        track's object with an end of it segmented or not (:func:`boxes.recuts`): if the
        track takes it, :meth:`update` holds it out of the filter when it grew by more than
        ``RECUT_GROWN``, else moves the track onto it without taking the jump for a motion."""
        self.line_ns = 0.0
        """How much later a rolling shutter reads each image row than the one above (ns); 0
        for a global shutter (set by the pipeline from ``readout_s``)."""
        self.view_px = view_px
        """The images' width and height (px): an unseen track whose motion is a guess and
        whose prediction leaves both has left the view (:meth:`_left_view`)."""
        g = np.asarray(params.gravity_mps2, dtype=np.float64)
        self._gravity: np.ndarray | None = g if np.any(g != 0.0) else None
        self._tracks: dict[int, Track] = {}
        self._next_id = 1

    def live_ids(self) -> list[int]:
        return list(self._tracks)

    def track(self, track_id: int) -> Track:
        return self._tracks[track_id]

    def histories(self, track_id: int | None) -> tuple[EyeHistory, EyeHistory] | None:
        """A track's two eye histories (for skew compensation), None for no track, or for one
        last seen in a blob it shared with an object behind it (its histories follow that)."""
        if track_id is None:
            return None
        tr = self._tracks[track_id]
        if tr.blended:
            return None
        return tr.left_history, tr.right_history

    def _movers(self, t_ns: int) -> list[tuple[np.ndarray, int]]:
        """The last left box (x, y, w, h px) of every track seen moving within
        ``still_after_s`` of ``t_ns`` (ns), and when: taken before a pair's new tracks start,
        so none of them counts, and no stale motion does."""
        recent = t_ns - int(self.params.still_after_s * 1e9)
        return [
            (tr.last.left_bbox_px, tr.last_moving_ns)
            for tr in self._tracks.values()
            if tr.last is not None and tr.last_moving_ns is not None
            and tr.last_moving_ns >= recent
        ]  # fmt: skip

    @staticmethod
    def _parted(ob: Observation, movers: list[tuple[np.ndarray, int]]) -> int | None:
        """When the latest of ``movers`` (:meth:`_movers`) whose box, grown by
        :data:`PARTED_GROW` of its size each way, overlaps this new observation's left box
        was seen moving (ns), else None. What parts from an object moving now (a box a robot
        pushed and leaves, a bag put down) moved with it or was put down by it: its
        background is held as a stopped object's, not learned in as if it had always stood
        there."""
        x, y, w, h = (float(v) for v in ob.left_bbox_px)
        latest: int | None = None
        for box, moved_ns in movers:
            ox, oy, ow, oh = (float(v) for v in box)
            gx, gy = PARTED_GROW * ow, PARTED_GROW * oh
            if x < ox + ow + gx and ox - gx < x + w and y < oy + oh + gy and oy - gy < y + h:
                latest = moved_ns if latest is None else max(latest, moved_ns)
        return latest

    def update(
        self,
        t_ns: int,
        observations: list[Observation | None],
        assignment: list[int | None],
        eye_times_ns: tuple[int, int],
        detections: list[Detection],
        blob_times_ns: list[tuple[int, int]] | None = None,
        blob_boxes_px: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[list[TrackState], list[int]]:
        """Fold in one pair's observations at ``t_ns`` (``None`` in ``observations`` is a
        detection that neither joins nor starts a track); ``eye_times_ns`` are the left and
        right capture instants of the frames, and ``blob_times_ns`` each detection's own (a
        rolling shutter reads its rows later; default: the frames'), and ``blob_boxes_px``
        every blob's box in each eye ((n, 4) x, y, w, h; default: the detections'), matched
        or not: a confirmed track unseen for longer than ``max_coast_s`` lives on, up to
        ``max_hidden_s``, while both eyes see a blob where it should be, or where the blob that
        hid it in the last pair was (it moved on, or parted; what comes out of it may be this
        track's object, see :meth:`associate`). Returns the state of
        every live track (observed or coasting) and the ids of the tracks that ended. A track
        whose filter puts it behind the rig (Z <= 0, where no camera sees) ends there: its
        filter has lost the object, and what it would publish means nothing."""
        p = self.params
        coast_ns = int(p.max_coast_s * 1e9)
        seen: set[int] = set()
        states: list[TrackState] = []
        ended: list[int] = []
        times = blob_times_ns if blob_times_ns is not None else [eye_times_ns] * len(detections)
        movers = self._movers(t_ns)
        for k, (ob, tid, det, (t_left, t_right)) in enumerate(
            zip(observations, assignment, detections, times, strict=True)
        ):
            if ob is None:
                continue
            blended = tid is not None and k in self._fronts
            piece = False
            if tid is not None and blended:
                front = self._tracks[tid]
                expected = kalman.point_at(front.kf, t_ns)[2] if front.started else None
                ob = measure.by_edge(ob, *self._fronts[k], front.outline_m, expected)
            if tid is None:
                kf = kalman.initiate(ob.position_m, ob.cov_m2, t_ns, p.manoeuvre_sigma_mps)
                tr = Track(
                    self._next_id,
                    first_t_ns=t_ns,
                    kf=kf,
                    last=ob,
                    image_speed_pxps=det.image_speed_pxps,
                    area_px=float(det.area_px),
                    last_seen_ns=t_ns,
                )
                self._next_id += 1
                tr.last_moving_ns = self._parted(ob, movers)
                self._tracks[tr.track_id] = tr
                self._begin(tr, t_ns, ob)
            else:
                tr = self._tracks[tid]
                recut = (k, tid) in self._recut and self._confirmed(tr) and not blended
                if (
                    recut
                    and _grown(tr.last, ob)
                    and not _reshaped(tr.last, ob)  # (one end of it showing again: taken)
                    and t_ns - tr.last_seen_ns <= coast_ns
                ):
                    # Its object joined by what its blob took in with it (a long shadow the
                    # detector did not leave out): unseen in this pair, its outline and 2D
                    # tracks kept to know it by when it shows alone again; after
                    # ``max_coast_s`` of it, the blob is taken for the object (it did grow).
                    continue
                regrown = not self._confirmed(tr) and _regrown(tr.last, ob)
                if regrown and not tr.odd_size:
                    # Another object's blob, or the object's own merged with something (a
                    # long shadow): held aside for this pair, neither a hit nor a miss.
                    tr.odd_size = True
                    seen.add(tr.track_id)
                    if tr.started or tr.whole:
                        states.append(self._state(tr, t_ns, observed=False))
                    continue
                tr.odd_size = False
                if regrown:  # a second pair running: the object is this width now
                    self._anew(tr, t_ns, ob)
                    tr.area_px = float(det.area_px)
                elif tr.member_of is not None:  # out of the object it was taken into: anew
                    tr.member_of = None
                    self._afresh(tr, t_ns, ob)
                elif tr.edge_begun and not ob.clipped:  # whole at last: a filter of whole outlines
                    self._afresh(tr, t_ns, ob)
                elif not tr.started:
                    self._begin(tr, t_ns, ob)
                elif ob.clipped and not ob.edge_depth:  # part of it out of view: predicted
                    self._predict(tr, t_ns)
                elif recut or (self._confirmed(tr) and not blended and _reshaped(tr.last, ob)):
                    self._anchor(tr, t_ns, ob)  # an end of it showed or went: not a motion
                    self._shift_histories(tr, ob, t_left, t_right)
                elif self._confirmed(tr) and blended and _off_edge(tr, ob, t_ns):
                    # The edge it is read by is not its own: predicted, and its last whole
                    # outline kept to tell the next pair's blob by.
                    piece = True
                    self._predict(tr, t_ns)
                elif self._confirmed(tr) and _shrunk(tr.last, ob):
                    # A piece of it shows, the rest hidden: folded in as loosely as the outline
                    # it is part of, and that outline kept as above.
                    piece = True
                    self._piece(tr, t_ns, ob)
                else:
                    self._filter(tr, t_ns, ob)
                tr.hits += 1
                tr.misses = 0
                tr.hidden_in = None
                if tr.blended and not blended:  # its own blob again: its 2D tracks start afresh
                    tr.left_history.clear()
                    tr.right_history.clear()
                tr.blended = blended
                if not piece:
                    tr.last = ob
                tr.last_seen_ns = t_ns
                tr.image_speed_pxps = det.image_speed_pxps
                tr.area_px = 0.8 * tr.area_px + 0.2 * det.area_px
            if not ob.clipped and not piece:
                tr.positions.append((t_ns, ob.position_m))
                if k not in self._shared:  # seen whole in a blob of its own
                    tr.outline_m = measure.outline_m(ob)
            tr.left_history.append((t_left, ob.left_px))
            tr.right_history.append((t_right, ob.right_px))
            seen.add(tr.track_id)
            if behind(tr):
                ended.append(tr.track_id)
                del self._tracks[tr.track_id]
            elif tr.started or tr.whole:  # a track seen only cut by the image's edge is quiet
                states.append(self._state(tr, t_ns, observed=True))
        hidden_ns = int(max(p.max_hidden_s, p.max_coast_s) * 1e9)
        boxes = blob_boxes_px or (
            np.array([d.left_bbox_px for d in detections]).reshape(-1, 4),
            np.array([d.right_bbox_px for d in detections]).reshape(-1, 4),
        )
        for tid, keeper in self._merging.items():
            if tid in self._tracks and tid not in seen and keeper in seen:
                self._take_in(self._tracks.pop(tid), keeper, t_ns)  # a piece of its object
        self._merging = {}
        for tid, tr in list(self._tracks.items()):
            if tid in seen:
                continue
            if tr.member_of is not None:  # given a blob that gave no position: still a member
                self._members[tid] = self._tracks.pop(tid)
                continue
            tr.misses += 1
            tr.odd_size = False  # a blob held aside counts again only in the next pair
            if not self._confirmed(tr):
                # An object entering the view is small, and one eye may miss it once: a track
                # seen once waits one pair for it. Any other tentative track ends unseen (a
                # blob that flickers on and off never gathers the hits to be confirmed).
                if tr.hits > 1 or tr.misses > 1:
                    ended.append(tid)
                    del self._tracks[tid]
                elif tr.started or tr.whole:
                    states.append(self._state(tr, t_ns, observed=False))
                continue
            tr.hidden_in = self._hiding(tr, eye_times_ns, boxes)
            unseen_ns = t_ns - tr.last_seen_ns
            if (unseen_ns > coast_ns and (tr.hidden_in is None or unseen_ns > hidden_ns)) or (
                self._left_view(tr, eye_times_ns)
            ):
                ended.append(tid)
                del self._tracks[tid]
            else:
                self._predict(tr, t_ns)
                if behind(tr):
                    ended.append(tid)
                    del self._tracks[tid]
                elif tr.started or tr.whole:
                    states.append(self._state(tr, t_ns, observed=False))
        member_ns = int(p.max_member_s * 1e9)
        for tid, tr in list(self._members.items()):
            if tr.member_of not in self._tracks or t_ns - tr.merged_ns > member_ns:
                ended.append(tid)  # its object ended, or it never came out of it
                del self._members[tid]
            else:
                tr.hidden_in = _held_in(tr.hidden_in, boxes)
        return states, ended

    def _left_view(self, tr: Track, eye_times_ns: tuple[int, int]) -> bool:
        """Whether an unseen track whose motion is a guess (no valid velocity) is predicted
        outside both images, by its size and an eighth of the image (a calibrated rig's
        rectified points reach past the frame): it ends, hidden or not, for its guess has left
        the view (a pedestrian's once coasted across and out of it for 1.6 s while blobs it
        had passed kept it hidden). One whose velocity is known coasts as long as ever: a ball
        thrown over the top of the view comes back."""
        if self.view_px is None or not tr.started or tr.speed_known:
            return False
        w, h = self.view_px
        margin = math.sqrt(tr.area_px) + 0.125 * max(w, h)
        pred = self._predict_px(tr, *self._row_instants(tr, eye_times_ns))
        return not any(
            -margin <= float(x) <= w + margin and -margin <= float(y) <= h + margin
            for x, y in (pred.left, pred.right)
        )

    def _shift_histories(self, tr: Track, ob: Observation, t_left: int, t_right: int) -> None:
        """Move each eye's 2D track of ``tr`` by how far ``ob``'s centroid (px) lies from
        where it leads at that eye's instant (ns): its centroid jumped with a change of shape
        (:func:`_reshaped`), and the image velocity the skew compensation takes from the
        history would otherwise read the jump as motion."""
        for history, now, t_e in (
            (tr.left_history, ob.left_px, t_left),
            (tr.right_history, ob.right_px, t_right),
        ):
            if not history:
                continue
            shift = now - predict_px(history, t_e, self.WINDOW_NS)[0]
            moved = [(t, px + shift) for t, px in history]
            history.clear()
            history.extend(moved)

    def _take_in(self, tr: Track, keeper: int, t_ns: int) -> None:
        """Make ``tr`` a member of ``keeper``'s object from ``t_ns`` (ns): it is followed as
        that object's blob (its boxes in each eye, :func:`_held_in`) until it comes out of it
        or ``max_member_s`` passes; its own members go to ``keeper`` with it."""
        tr.member_of, tr.merged_ns = keeper, t_ns
        last = self._tracks[keeper].last
        tr.hidden_in = (last.left_bbox_px.copy(), last.right_bbox_px.copy())
        for member in self._members.values():
            if member.member_of == tr.track_id:
                member.member_of = keeper
        self._members[tr.track_id] = tr

    def _hiding(
        self, tr: Track, eye_times_ns: tuple[int, int], boxes: tuple[np.ndarray, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """What hides a track unseen in this pair: in each eye, the union of the blobs seen
        (``boxes``: each eye's, x, y, w, h px) where it should be, or where the blob that hid it
        in the last pair was (that blob moved on, or parted in two: a person coming out from
        behind another is not where a short-lived track's guessed velocity puts them); None
        when an eye has none (nothing hides it)."""
        pred = self._predict_px(tr, *self._row_instants(tr, eye_times_ns))
        out = []
        for e, point in enumerate((pred.left_far, pred.right_far)):
            before = tr.hidden_in[e] if tr.hidden_in is not None else None
            hit = [
                b
                for b in boxes[e]
                if inside(point, b, 0.0) or (before is not None and overlaps(b, before))
            ]
            if not hit:
                return None
            out.append(union(hit))
        return out[0], out[1]

    def continue_after(self, other: Tracker) -> None:
        """Number new tracks after ``other``'s, so ids are never reused while running."""
        self._next_id = max(self._next_id, other._next_id)

    def end_all(self) -> list[int]:
        """End every live track and member (end of input); return their ids."""
        ids = list(self._tracks) + list(self._members)
        self._tracks.clear()
        self._members.clear()
        return ids


def _held_in(
    before: tuple[np.ndarray, np.ndarray] | None, boxes: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where an object's blob is now, in each eye, given where it was (``before``: left and
    right boxes, x, y, w, h px) and this pair's blobs (``boxes``, (n, 4) per eye): the union of
    the blobs that overlap it (it moved, or parted in two), or where it was if none does (the
    object unseen in that eye)."""
    if before is None:
        return None
    out = []
    for e in range(2):
        hit = [b for b in boxes[e] if overlaps(b, before[e])]
        out.append(union(hit) if hit else before[e])
    return out[0], out[1]


REGROWN = 2.5
"""A tentative track's blob whose width in metres (its box's width in px times its depth over
the focal length) differs from its last one's by more than this factor is not its object
seen once more: a ball that merged with its long shadow (2.96 times as wide in px, 3.2 times
in metres, 0.693 against 0.216 m: the merged blob's depth reads too far as well), a piece and
then the whole. Such a blob is held aside for one pair (another object's first blob, given
to the track, then starts its own track a pair later); if the next pair's blob is again
beyond this factor of the track's last one, the track begins again from it."""


def _regrown(last: Observation, ob: Observation) -> bool:
    """Whether ``ob``'s width (m) and ``last``'s differ by more than :data:`REGROWN` (clipped
    outlines aside: an object entering past the image's side grows as it comes in)."""
    if ob.clipped or last.clipped or not (ob.size_m > 0.0 and last.size_m > 0.0):
        return False
    return max(ob.size_m / last.size_m, last.size_m / ob.size_m) > REGROWN


RECUT_GROWN = 2.5
"""A confirmed track's re-segmented blob (:func:`stereod.tracking.boxes.recuts`) whose box
has more than this times the area of its last one's in both eyes has taken in something
beside its object (a ball's box with its long shadow: 3.7 times), more than an object grows
by in a pair."""


def _grown(last: Observation, ob: Observation) -> bool:
    """Whether ``ob``'s box is more than :data:`RECUT_GROWN` times the area (px^2) of
    ``last``'s in both eyes (x, y, w, h px)."""
    for now, then in ((ob.left_bbox_px, last.left_bbox_px), (ob.right_bbox_px, last.right_bbox_px)):
        if float(now[2]) * float(now[3]) <= RECUT_GROWN * float(then[2]) * float(then[3]):
            return False
    return True


SHRINK = 0.5
"""A blob whose box, across and down, is under this share of a confirmed track's last one in
either eye is a piece of the object (the rest hidden behind another), not the object."""


def _shrunk(last: Observation, ob: Observation) -> bool:
    """Whether ``ob``'s boxes are, in either eye, under ``SHRINK`` of ``last``'s in both
    width and height (x, y, w, h px)."""
    for now, then in ((ob.left_bbox_px, last.left_bbox_px), (ob.right_bbox_px, last.right_bbox_px)):
        if float(now[2]) < SHRINK * float(then[2]) and float(now[3]) < SHRINK * float(then[3]):
            return True
    return False


RESHAPED = 1.25
"""A blob whose box in either eye grew or shrank in height by more than this factor since a
confirmed track's last one, by more than ``2 * RESHAPE_END_PX``, one end of it staying
within ``RESHAPE_END_PX`` and its width within ``RESHAPE_WIDTH`` of what they were, is the
object with one end of it segmented or not (a person's legs as pale as the floor behind
them), not the object moving: one coming nearer grows both ways and at both ends at once."""
RESHAPE_WIDTH = 1.15
RESHAPE_END_PX = 3.0
"""How far (px) the end of a box that stayed may move: a segmentation's edge is a pixel or
two off, and a walker's head bobs."""


def _reshaped(last: Observation, ob: Observation) -> bool:
    """Whether ``ob``'s boxes changed in height at one end only, not in width, from
    ``last``'s in an eye (:data:`RESHAPED`; x, y, w, h px): its centroid moved by what the
    segmentation took in or left out."""
    for now, then in ((ob.left_bbox_px, last.left_bbox_px), (ob.right_bbox_px, last.right_bbox_px)):
        y, h, w = float(now[1]), float(now[3]), float(now[2])
        y0, h0, w0 = float(then[1]), float(then[3]), float(then[2])
        if min(h, h0, w, w0) <= 0 or abs(h - h0) <= 2 * RESHAPE_END_PX:
            continue
        one_end = abs(y - y0) <= RESHAPE_END_PX or abs(y + h - y0 - h0) <= RESHAPE_END_PX
        if one_end and max(h / h0, h0 / h) > RESHAPED and max(w / w0, w0 / w) <= RESHAPE_WIDTH:
            return True
    return False


def _off_edge(tr: Track, ob: Observation, t_ns: int) -> bool:
    """Whether a reading by its free edge (:func:`stereod.tracking.measure.by_edge`) puts a
    track further across from where its filter predicts it at ``t_ns`` (ns) than its own
    outline is wide (m, :attr:`Track.outline_m`): the edge taken is not its own, but what
    shows of the other object beyond it (two people just past each other: a 0.3 m jump set a
    1.2 m/s walker's velocity to 1.8 m/s, and the other took their id as they parted)."""
    if tr.outline_m is None or not ob.edge_depth:
        return False
    across = abs(float(ob.position_m[0]) - kalman.point_at(tr.kf, t_ns)[0])
    return across > tr.outline_m[0] + tr.outline_m[1]


PARTED_GROW = 0.25
"""How far (a share of its width and height, each way) a moving track's last box is grown to
hold a new track that parted from it (:meth:`Tracker._parted`): as far as a piece of
it may lie from it (``association``'s pieces, within a quarter), and a piece that may start
a track of its own lies just beyond that."""

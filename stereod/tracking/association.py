"""Association in the images: where each track should be seen in each eye, the gate and cost
of each detection to each track, pieces and crossings, and the assignment (confirmed tracks
first)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from stereod.tracking import boxes, kalman
from stereod.tracking.assignment import min_cost_assignment
from stereod.tracking.skew import image_velocity, shift_to
from stereod.tracking.track import Track, TrackFilters
from stereod.tracking.types import Detection, EyeHistory

Projector = Callable[[float, float, float, bool], tuple[float, float]]
"""A rig-frame point (x, y, z m) to rectified px (x, y) of the left eye (True) or the right
(False), as :meth:`stereod.vision.geometry.stereo.Rectified.project` does."""


def predict_px(history: EyeHistory, t_ns: int, window_ns: int) -> tuple[np.ndarray, float]:
    """Where one eye's 2D track puts the object at ``t_ns`` (px), and how far (px) it moved
    in the image since its last centroid (0 without a velocity)."""
    t_last, last = history[-1]
    v = image_velocity(history, window_ns)
    if v is None:
        return last, 0.0
    moved = shift_to(last, t_last, v, t_ns)
    return moved, _dist(moved, last)


@dataclass(frozen=True, slots=True)
class Prediction:
    """Where a track should be seen in each eye (px): at ``left`` or anywhere on the segment
    to ``left_far`` (likewise right), and how far that is from where each eye last saw it."""

    left: np.ndarray
    left_far: np.ndarray
    right: np.ndarray
    right_far: np.ndarray
    left_motion: float
    right_motion: float


def _dist(a: np.ndarray, b: np.ndarray) -> float:
    """Distance (px) between two image points (2,) (math on two floats: numpy's per-call
    cost is most of the work on a pair of coordinates)."""
    return math.hypot(float(a[0]) - float(b[0]), float(a[1]) - float(b[1]))


def _motion(a: np.ndarray, b: np.ndarray, last: np.ndarray) -> float:
    """The larger distance (px) of two predictions from the last centroid."""
    return max(_dist(a, last), _dist(b, last))


def _pieces(
    detections: list[Detection],
    centres: np.ndarray,
    bboxes: np.ndarray,
    owners: list[int | None],
    tracks: list[Track],
) -> np.ndarray:
    """Which detections ((n,) bool) lie within a larger one of this pair, or within the box of
    a track that was found this pair, in both eyes: a piece of that object, not another.
    ``centres`` (n, 2, 2) and ``bboxes`` (n, 2, 4) are the detections' centroids and boxes,
    left and right eye."""
    areas = np.array([d.area_px for d in detections])
    within = (
        boxes.insides(centres[:, 0], bboxes[:, 0])
        & boxes.insides(centres[:, 1], bboxes[:, 1])
        & (areas[:, None] > areas[None, :])
    )  # (larger one, piece)
    piece = within.any(axis=0)
    found = {tid for tid in owners if tid is not None}
    held = [tr for tr in tracks if tr.track_id in found]
    if held:
        left = np.array([tr.last.left_bbox_px for tr in held]).reshape(-1, 4)
        right = np.array([tr.last.right_bbox_px for tr in held]).reshape(-1, 4)
        inside = boxes.insides(centres[:, 0], left, 0.25) & boxes.insides(
            centres[:, 1], right, 0.25
        )
        piece |= inside.any(axis=0)
    return piece


NEARER = 1.5
"""A detection whose disparity is more than this many times a hidden track's predicted one
(and :data:`DISPARITY_SLACK_PX` more) is nearer than that track's object, at two thirds of its
depth or less: another object in front of it, not it joined by its shadow or a neighbour
(whose blend of disparities lies between)."""
DISPARITY_SLACK_PX = 2.0
GONE_WIDTH = 0.8
"""A blob at most this share of a track's own width (its outline seen whole, at its predicted
depth) in both eyes cannot hold that object whole (:meth:`Association._gone_from_front`)."""


def _disparities(
    centres: np.ndarray, ends: np.ndarray, started: list[bool], detections: list[Detection]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The detections' disparities ((n,) px, from ``centres`` (n, 2, 2): left and right
    centroids), the tracks' predicted ones ((k,) px, from ``ends[0]`` and ``ends[2]``: left
    and right predictions), and which pairs of the two can be compared ((n, k) bool: a track
    whose filter runs, ``started``, and a detection whose disparity is its object's, not cut
    by the image's side, which shows each eye another part of it)."""
    d = centres[:, 0, 0] - centres[:, 1, 0]
    dp = ends[0][:, 0] - ends[2][:, 0]
    judged = (
        np.asarray(started, bool)[None, :]
        & ~np.array([det.clipped for det in detections], bool)[:, None]
    )
    return d, dp, judged


def _stacked(a: Track, b: Track) -> bool:
    """Whether two tracks' last boxes share columns in both eyes (x, y, w, h px): one lies
    above the other, as a person's head, torso and legs do."""
    for p, q in (
        (a.last.left_bbox_px, b.last.left_bbox_px),
        (a.last.right_bbox_px, b.last.right_bbox_px),
    ):
        if min(float(p[0] + p[2]), float(q[0] + q[2])) <= max(float(p[0]), float(q[0])):
            return False
    return True


RESUME_COST = 0.99
"""The association cost (of at most 1, the gate's edge) of a confirmed track and a detection
beyond its gate that overlaps where it was (``RESUME_IOU``), or that is its object
re-segmented (:func:`stereod.tracking.boxes.recuts`): the worst acceptable, so any detection
the track's prediction explains is preferred."""
RESUME_IOU = 0.3
"""How much a detection's box must overlap a confirmed track's last box, in each eye, to be
that object moving on though its prediction is not there (a stationary object setting off:
its filter predicts it where it stood, and the first step of a start can lie outside the gate
of an object at rest; a person or robot starting off moves a fraction of its size in a
frame; a ball 17 px across that sets off at 0.4 m/s, 7 px a frame, keeps 0.4)."""


class Association(TrackFilters):
    """The tracker's work across tracks in one pair: :meth:`associate` detections to tracks."""

    _project: Projector | None
    _merging: dict[int, int]
    _members: dict[int, Track]
    _fronts: dict[int, tuple[bool, float]]
    _shared: set[int]
    _recut: set[tuple[int, int]]
    line_ns: float
    _tracks: dict[int, Track]

    WINDOW_NS = 150_000_000
    """How much of an eye's 2D track its image velocity is fitted over (ns)."""

    def associate(
        self, detections: list[Detection], eye_times_ns: tuple[int, int]
    ) -> tuple[list[int | None], list[bool]]:
        """The track each detection belongs to (``None``: none), and whether a detection
        without a track may start one (not a piece of a live object, not two objects merged,
        not background a moved object uncovered: that is no object, and no track takes it)."""
        p = self.params
        n = len(detections)
        out: list[int | None] = [None] * n
        may_start = [True] * n
        tracks = list(self._tracks.values())
        self._merging = {}
        self._fronts = {}
        self._shared = set()
        self._recut = set()
        if not detections:
            return out, may_start
        centres = np.array([(d.left_px, d.right_px) for d in detections], np.float64)
        bboxes = np.array([(d.left_bbox_px, d.right_bbox_px) for d in detections], np.float64)
        gone = np.array([d.uncovered for d in detections])
        if not tracks:
            return out, (~_pieces(detections, centres, bboxes, out, []) & ~gone).tolist()
        k = len(tracks)
        confirmed = np.array([self._confirmed(tr) for tr in tracks])
        preds: list[Prediction] = []
        gates = np.empty(k)
        ends = np.empty((4, k, 2))  # each track's predicted segments: left, left_far, right, ...
        last = np.empty((2, k, 4))  # and its last boxes, left and right (x, y, w, h px)
        for j, tr in enumerate(tracks):
            t_left, t_right = self._row_instants(tr, eye_times_ns)
            pred = self._predict_px(tr, t_left, t_right)
            pl, pr, ml, mr = pred.left, pred.right, pred.left_motion, pred.right_motion
            preds.append(pred)
            if len(tr.left_history) >= 2 and len(tr.right_history) >= 2:
                moved = max(ml, mr)
                if tr.misses > 0:  # unseen: credited no more than its image velocity carries it
                    moved = min(moved, self._unseen_motion(tr, t_left, t_right))
                gate = p.gate_px + p.motion_gate * moved
            else:
                dt = max(t_left - tr.left_history[-1][0], t_right - tr.right_history[-1][0])
                gate = p.gate_px + tr.image_speed_pxps * dt * 1e-9
            gates[j] = max(gate, p.size_gate * math.sqrt(tr.area_px))
            ends[:, j] = pl, pred.left_far, pr, pred.right_far
            last[:, j] = tr.last.left_bbox_px, tr.last.right_bbox_px
        # Every detection against every track at once. Its distance (px) from the track's
        # prediction, the larger of the eyes': within the gate, that over the gate is its cost.
        # Beyond it, a confirmed track's detection that overlaps where it was in both eyes (a
        # stationary object setting off) costs RESUME_COST.
        cost_px = np.maximum(
            boxes.to_segments(centres[:, 0], ends[0], ends[1]),
            boxes.to_segments(centres[:, 1], ends[2], ends[3]),
        )
        within = cost_px <= gates
        cost = np.where(within, cost_px / gates, np.inf)
        resumes = ~within & confirmed
        if resumes.any():  # (the overlaps only where a confirmed track's gate missed)
            # A detection whose boxes and the track's predicted ones hold one another with
            # their ends shared (``recuts``), in both eyes, is its object with an end of it
            # segmented or not (a ball and its long shadow, then the ball alone): its
            # centroid jumped by a change of shape, which :meth:`update` does not take for a
            # motion.
            # (Only the one blob where the track should be: two there are its object and
            # another parting, as a robot leaves the box it pushed.)
            recut = resumes.copy()
            missed = np.flatnonzero(resumes.any(axis=0))  # (the tracks with such a detection)
            for e, left in ((0, True), (1, False)):
                predicted = self._predicted_boxes(
                    [tracks[j] for j in missed], [preds[j] for j in missed], left
                )
                touch = boxes.ious(bboxes[:, e], predicted) > 0
                recut[:, missed] &= boxes.recuts(bboxes[:, e], predicted) & touch
                recut[:, missed] &= touch.sum(axis=0) == 1  # the one blob there
            resumes &= boxes.ious(bboxes[:, 0], last[0]) >= RESUME_IOU
            resumes &= boxes.ious(bboxes[:, 1], last[1]) >= RESUME_IOU
            cost[resumes | recut] = RESUME_COST
            self._recut = {(int(i), tracks[int(j)].track_id) for i, j in np.argwhere(recut)}
        # whether each track's prediction falls in each detection's box, left and right eye
        inside = np.stack(
            (boxes.insides(ends[0], bboxes[:, 0]), boxes.insides(ends[2], bboxes[:, 1]))
        )
        # A detection clearly nearer than a hidden track (its disparity against the track's
        # predicted one, as a difference: a fast object's centroids, taken at two instants,
        # may read a small or negative disparity, where ratios mean nothing) does not hold it
        # (below): it is another object, in front of it (a board held up before a person).
        seen_d, predicted_d, judged = _disparities(
            centres, ends, [tr.started for tr in tracks], detections
        )
        dpp = predicted_d[None, :]
        nearer = judged & (
            seen_d[:, None] - dpp > (NEARER - 1.0) * np.maximum(dpp, 0.0) + DISPARITY_SLACK_PX
        )
        cost[gone] = np.inf
        shared: list[int] = []
        if int(np.count_nonzero(confirmed)) >= 2:  # (one confirmed track shares nothing)
            hosted = (inside & confirmed).sum(axis=2)  # (eye, detection): confirmed tracks in it
            shared = np.flatnonzero(~gone & ((hosted[0] >= 2) | (hosted[1] >= 2))).tolist()
        for i in shared:
            d = detections[i]
            in_left, in_right = inside[0, i] & confirmed, inside[1, i] & confirmed
            hosts = np.flatnonzero(in_left | in_right)
            self._shared.add(i)
            if self._one_object([tracks[j] for j in hosts]):
                # Pieces of one object that were followed apart (an arm, a torso) now seen
                # whole: the longest-followed track takes it, the others end into it.
                held = [int(h) for h in hosts]
                keeper = max(held, key=lambda h: (tracks[h].hits, -tracks[h].track_id))
                keep = min(cost[i, keeper], RESUME_COST)
                cost[i, :] = np.inf
                cost[i, keeper] = keep
                for h in held:
                    if h != keeper:
                        self._merging[tracks[h].track_id] = tracks[keeper].track_id
                may_start[i] = False
                continue
            # Two objects in one blob, in one eye or both: its centroid is a blend of both. The
            # nearer one, clearly in front, is whole in it, the other joining it on one side:
            # it is seen by its outline's other side, like an object cut by the image's edge
            # (:meth:`_in_front`). Else it is one of them (the other hidden behind it) if it
            # looks like that one alone: its box where that one's box should be, in both eyes.
            # Failing both, both coast until they part in both eyes.
            # A detection clearly farther than a track (the nearer test the other way round)
            # may be that object in front with a larger one behind joining it (a ball before a
            # person: the blend of their disparities is near the person's); but not when it
            # is clearly narrower than that object (:meth:`_gone_from_front`).
            farther = judged[i] & (
                NEARER * max(float(seen_d[i]), 0.0) + DISPARITY_SLACK_PX < predicted_d
            )
            left_in = [j for j in hosts if not (farther[j] and self._gone_from_front(d, tracks[j]))]
            front = self._in_front(tracks, np.array(left_in, np.intp), inside[:, i], preds)
            if front is not None:
                keep = min(cost[i, front[0]], RESUME_COST)
                cost[i, :] = np.inf
                cost[i, front[0]] = keep
                self._fronts[i] = front[1:]
                may_start[i] = False
                continue
            alone = [
                j
                for j in hosts
                if np.isfinite(cost[i, j])
                and boxes.iou(d.left_bbox_px, self._predicted_box(tracks[j], preds[j], True)) >= 0.9
                and boxes.iou(d.right_bbox_px, self._predicted_box(tracks[j], preds[j], False))
                >= 0.9
            ]
            keep = cost[i, alone[0]] if len(alone) == 1 else np.inf
            cost[i, :] = np.inf
            if len(alone) == 1:
                cost[i, alone[0]] = keep
            may_start[i] = False
        # Confirmed tracks choose first, then tentative ones among what is left: a tentative
        # track seen once has a gate as wide as max_speed_mps allows, so its cost (distance
        # over gate) is small, and it would take a confirmed object's detection from it.
        for group in (confirmed, ~confirmed):
            cols_in = np.flatnonzero(group)
            rows_in = np.array([i for i in range(n) if out[i] is None], np.intp)
            if not (cols_in.size and rows_in.size):
                continue
            if cols_in.size == 1 and rows_in.size == 1:  # one of each: no choice to make
                i, j = int(rows_in[0]), int(cols_in[0])
                if math.isfinite(cost[i, j]):
                    out[i] = tracks[j].track_id
                continue
            sub = cost[np.ix_(rows_in, cols_in)]
            feasible = np.isfinite(sub)
            if not feasible.any():
                continue
            rows, cols = min_cost_assignment(np.where(feasible, sub, 1e9))
            for i, j in zip(rows, cols, strict=True):
                if feasible[i, j]:
                    out[rows_in[i]] = tracks[cols_in[j]].track_id
        # A blob that holds, in both eyes, where a confirmed track left unmatched should be is
        # that object disturbed (joined by a shadow the detector did not leave out, or by
        # another object): it starts no track of its own while that one lives on, hidden. One
        # clearly nearer than that track is another object, in front of it, that hides it.
        taken = {t for t in out if t is not None}
        unseen = [j for j, tr in enumerate(tracks) if confirmed[j] and tr.track_id not in taken]
        free = [i for i in range(n) if out[i] is None and may_start[i]]
        if free:  # (pieces matter only to a detection that may still start a track)
            piece = _pieces(detections, centres, bboxes, out, tracks)
            for i in free:
                holds = any(
                    inside[0, i, j] and inside[1, i, j] and not nearer[i, j] for j in unseen
                )
                may_start[i] = not holds and not bool(piece[i]) and not gone[i]
        # A blob that would start a track but came out, in both eyes, of the blob that hid a
        # confirmed track in the last pair is that object reappearing (two people who crossed
        # part): it takes that track, the nearest to its prediction if several.
        for i, d in enumerate(detections):
            if out[i] is not None or not may_start[i]:
                continue
            came_out = [
                j
                for j in unseen
                if tracks[j].track_id not in taken
                and (hid := tracks[j].hidden_in) is not None
                and boxes.inside(d.left_px, hid[0], 0.0)
                and boxes.inside(d.right_px, hid[1], 0.0)
            ]
            if came_out:
                tid = tracks[min(came_out, key=lambda j: cost_px[i, j])].track_id
                out[i] = tid
                taken.add(tid)
                continue
            # Or out of the object a member was taken into (a box a robot pushed, that it now
            # leaves): it is that member again, the nearest to where it was last seen if several.
            out_of = [
                m
                for m in self._members.values()
                if (hid := m.hidden_in) is not None
                and boxes.inside(d.left_px, hid[0], 0.0)
                and boxes.inside(d.right_px, hid[1], 0.0)
            ]
            if out_of:
                m = min(
                    out_of,
                    key=lambda m: max(
                        _dist(d.left_px, m.left_history[-1][1]),
                        _dist(d.right_px, m.right_history[-1][1]),
                    ),
                )
                del self._members[m.track_id]
                m.blended = True  # its 2D histories are of before: skew compensation waits
                self._tracks[m.track_id] = m
                out[i] = m.track_id
        return out, may_start

    def _gone_from_front(self, d: Detection, tr: Track) -> bool:
        """Whether a track predicted in front of what is behind it, in a blob clearly farther
        than it, has gone from that blob: the blob is narrower than :data:`GONE_WIDTH` of the
        object's own width (its outline seen whole, at its predicted depth) in both eyes, so
        it cannot hold it (what was behind a board taken away; a ball in front of a person
        is whole in the blob of the two, as wide as the person)."""
        if self._project is None or tr.outline_m is None or not tr.started:
            return False
        x, y, z = (float(v) for v in tr.kf.position_m)
        if z <= 0.0:
            return False
        for box, left in ((d.left_bbox_px, True), (d.right_bbox_px, False)):
            a = self._project(x - tr.outline_m[0], y, z, left)[0]
            b = self._project(x + tr.outline_m[1], y, z, left)[0]
            if float(box[2]) > GONE_WIDTH * abs(b - a):
                return False
        return True

    @classmethod
    def _predicted_boxes(
        cls, tracks: list[Track], preds: list[Prediction], left: bool
    ) -> np.ndarray:
        """Every track's :meth:`_predicted_box` in one eye: (k, 4) x, y, w, h px."""
        out = [cls._predicted_box(tr, p, left) for tr, p in zip(tracks, preds, strict=True)]
        return np.array(out, np.float64).reshape(-1, 4)

    @staticmethod
    def _predicted_box(tr: Track, pred: Prediction, left: bool) -> np.ndarray:
        """A track's last box in one eye (x, y, w, h px) moved to where ``pred`` puts it."""
        if left:
            return boxes.moved(tr.last.left_bbox_px, pred.left - tr.left_history[-1][1])
        return boxes.moved(tr.last.right_bbox_px, pred.right - tr.right_history[-1][1])

    def _in_front(
        self, tracks: list[Track], hosts: np.ndarray, inside: np.ndarray, preds: list[Prediction]
    ) -> tuple[int, bool, float] | None:
        """Which of the confirmed tracks whose predictions fall in one detection (``hosts``,
        indices into ``tracks``) is in front of the others, on which side they join it (True:
        its right, so its left edges are its own), and the largest disparity (px) predicted for
        them (``preds``: each track's predicted centroids); None if none is. In front: the
        nearest by its filter, nearer than each other one by more than ``merge_depth_m`` and
        three sigmas of their filters' depths (two at about one depth, or one whose depth is
        a guess, may be either way round), predicted inside the detection in both eyes
        (``inside`` (2, tracks)), with every other one predicted on one side of it."""
        started = [int(j) for j in hosts if tracks[int(j)].started]
        if len(started) < 2:
            return None
        depth = {j: float(tracks[j].kf.position_m[2]) for j in started}
        front = min(started, key=lambda j: depth[j])
        others = [j for j in started if j != front]
        sigma = {j: math.sqrt(max(float(tracks[j].kf.P[2, 2]), 0.0)) for j in started}
        if not (inside[0, front] and inside[1, front]) or any(
            depth[j] - depth[front]
            <= max(self.params.merge_depth_m, 3.0 * math.hypot(sigma[j], sigma[front]))
            for j in others
        ):
            return None
        x = float(preds[front].left[0])
        right = [float(preds[j].left[0]) > x for j in others]
        behind = max(float(preds[j].left[0]) - float(preds[j].right[0]) for j in others)
        return (front, right[0], behind) if len(set(right)) == 1 else None

    def objects(self, owners: list[int | None]) -> list[int | None]:
        """Each pair's track (``owners``, as :meth:`associate` gives them; None: none), with
        the confirmed tracks that are pieces of one object (:meth:`_one_object`, pair by pair,
        and so on transitively) given one id, the longest-followed one's: the grouping keeps
        two tracks' pairs apart as two objects, and pieces of a person followed apart (a head,
        a torso, the legs) would otherwise never be one object again. Only pieces one above
        the other (:func:`_stacked`): a robot and the box it pushes, side by side, stay two
        until one blob holds both (grouped each frame, the box came out of the robot's object
        with an id of its own)."""
        live = sorted({t for t in owners if t is not None and t in self._tracks})
        pieces = [t for t in live if self._confirmed(self._tracks[t])]
        root = {t: t for t in live}

        def find(t: int) -> int:
            while root[t] != t:
                t = root[t]
            return t

        for a in range(len(pieces)):
            for b in range(a + 1, len(pieces)):
                ta, tb = pieces[a], pieces[b]
                pa, pb = self._tracks[ta], self._tracks[tb]
                if find(ta) != find(tb) and _stacked(pa, pb) and self._one_object([pa, pb]):
                    ra, rb = find(ta), find(tb)
                    keep = max((ra, rb), key=lambda t: (self._tracks[t].hits, -t))
                    root[ra] = root[rb] = keep
        return [None if t is None or t not in root else find(t) for t in owners]

    def _one_object(self, tracks: list[Track]) -> bool:
        """Whether confirmed tracks that one detection holds are pieces of one object: at one
        depth (within ``merge_depth_m``) and moving together (velocities within
        ``merge_speed_mps``). Two balls crossing at different depths, or two people crossing
        each other's path, are not."""
        p = self.params
        if len(tracks) < 2 or not all(tr.started for tr in tracks):
            return False
        for a in range(len(tracks)):
            for b in range(a + 1, len(tracks)):
                ka, kb = tracks[a].kf, tracks[b].kf
                if abs(float(ka.position_m[2] - kb.position_m[2])) > p.merge_depth_m:
                    return False
                if float(np.linalg.norm(ka.velocity_mps - kb.velocity_mps)) > p.merge_speed_mps:
                    return False
        return True

    def _unseen_motion(self, tr: Track, t_left: int, t_right: int) -> float:
        """How far (px, the larger of the eyes) a track unseen since its last observation may
        have moved in the images by ``t_left``/``t_right`` (ns): as far as each eye's image
        velocity while it was seen carries it. Its filter's prediction may run much further
        (a few bad depths as an object leaves the view switch it to free fall, and in a third
        of a second unseen it predicts 200 px), and half of that as a gate would take a blob
        of the background that object uncovered, far from anywhere it went."""
        return max(
            predict_px(tr.left_history, t_left, self.WINDOW_NS)[1],
            predict_px(tr.right_history, t_right, self.WINDOW_NS)[1],
        )

    def _row_instants(self, tr: Track, eye_times_ns: tuple[int, int]) -> tuple[int, int]:
        """When each eye's rolling shutter reads the rows a track was last seen on (ns): the
        frame's instant plus that row times ``line_ns``."""
        if self.line_ns <= 0.0:
            return eye_times_ns
        rows = (float(tr.last.left_image_px[1]), float(tr.last.right_image_px[1]))
        return (
            eye_times_ns[0] + round(max(rows[0], 0.0) * self.line_ns),
            eye_times_ns[1] + round(max(rows[1], 0.0) * self.line_ns),
        )

    def _predict_px(self, tr: Track, t_left: int, t_right: int) -> Prediction:
        """Where each eye should see a track at its capture instant (px), and how far that is
        from where it last saw it (px). A track whose filter runs: the filter's prediction
        projected. Before that: its image velocity's lead, and with two positions, also the
        line through them projected (a fast object's image motion speeds up, but its first
        position may be off by the eyes' skew): it may be anywhere between the two. A track
        last seen cut by the image's edge (its filter only predicted, its centroid moving with
        the cut) may be anywhere between its filter's projection and its image velocity's
        lead."""
        last_l, last_r = tr.left_history[-1][1], tr.right_history[-1][1]
        far: tuple[np.ndarray, np.ndarray] | None = None
        if self._project is not None and tr.started:
            accel = self._accel(tr.falling)
            at = [kalman.point_at(tr.kf, t, accel) for t in (t_left, t_right)]
            far = self._projected(at[0], at[1], tr.last.depth_factor)
            if far is not None and not tr.last.clipped:
                pl, pr = far
                return Prediction(pl, pl, pr, pr, _dist(pl, last_l), _dist(pr, last_r))
        elif self._project is not None and len(tr.positions) >= 2:
            (t0, p0), (t1, p1) = tr.positions[-2], tr.positions[-1]
            v = (p1 - p0) / ((t1 - t0) * 1e-9)
            at_l, at_r = ((p1 + v * ((t - t1) * 1e-9)).tolist() for t in (t_left, t_right))
            far = self._projected(at_l, at_r, tr.last.depth_factor)
        pl, ml = predict_px(tr.left_history, t_left, self.WINDOW_NS)
        pr, mr = predict_px(tr.right_history, t_right, self.WINDOW_NS)
        pl2, pr2 = far if far is not None else (pl, pr)
        return Prediction(
            pl, pl2, pr, pr2, max(ml, _motion(pl2, pl2, last_l)), max(mr, _motion(pr2, pr2, last_r))
        )

    def _projected(
        self, at_left: Sequence[float], at_right: Sequence[float], depth_factor: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Where each eye sees the silhouette's centroid (px) of an object centred at rig-frame
        positions (x, y, z m) at that eye's instant: the centre projected from ``depth_factor``
        times nearer (a 10 cm ball at 1 m, at the edge of a 640 px wide image, is seen 3 px
        further out than its centre projects); ``None`` behind the cameras."""
        xl, yl, zl = at_left
        xr, yr, zr = at_right
        if self._project is None or zl <= 0 or zr <= 0:
            return None
        left = self._project(xl, yl, zl / depth_factor, True)
        right = self._project(xr, yr, zr / depth_factor, False)
        return np.array(left), np.array(right)

"""Multi-target tracking metrics: GOSPA (with its parts), OSPA, id switches, fragmentations, RMSE, NEES.

* GOSPA with ``alpha = 2`` (Rahmathullah, García-Fernández, Svensson, "Generalized optimal
  sub-pattern assignment metric", FUSION 2017): for truth positions ``X`` (n) and track
  positions ``Y`` (m), ``GOSPA^p = min over assignments of sum d(x, y)^p + c^p / 2 (n + m - 2|A|)``
  where only pairs with ``d < c`` are assigned. It splits into ``localisation`` (the sum over
  assigned pairs), ``missed`` (``c^p / 2`` per unassigned truth) and ``false`` (``c^p / 2``
  per unassigned track): ``GOSPA = (localisation + missed + false)^(1/p)``. The parts are
  reported in that p-th power scale so that they add up.
* OSPA (Schuhmacher, Vo, Vo, "A consistent metric for performance evaluation of multi-object
  filters", IEEE TSP 2008): ``(1/max(n, m) (min sum min(d, c)^p + c^p |m - n|))^(1/p)``.
* Both assignments use ``scipy.optimize.linear_sum_assignment`` on ``min(d, c)^p``.
* Per truth, the sequence of assigned track ids gives **id switches** (the id changes from one
  assigned picture to the next assigned one) and **fragmentations** (an assigned stretch ends
  and a later one starts).
* ``--horizontal``: GOSPA, OSPA and the RMSE on x, y only (a picture on the Earth, where a radar's
  altitude is far worse than its horizontal position); the **altitude error** (RMSE and mean of
  track minus truth z over the assigned pairs, when both are 3-D) is reported on its own. A track marked
  ``"alt_measured": false`` (its altitude nobody measured: ``fedtrack.geodetic.altitude_unmeasured``) is scored
  on x, y in the 3-D GOSPA, OSPA and RMSE (its distance to every truth the horizontal one), in the NEES on its
  ``[x, vx, y, vy]`` and their block of ``P`` (4 and 2 dof), and left out of the altitude error; how many
  assigned pairs were so is reported.
* Position RMSE over assigned pairs. **NEES** ``e' P^-1 e`` over the assigned pairs whose state
  sizes agree (a 2-D track against a 3-D truth: the truth's ``[x, vx, y, vy]``, the prefix of its
  ``[x, vx, y, vy, z, vz]``), in two parts with their degrees of freedom: the full ``state`` (4 or 6) and the
  ``position`` alone (its block of ``P``: 2 or 3); per part the mean, the fraction inside the
  two-sided 95% chi-square band of its dof (a consistent filter puts 95% of its pairs there)
  and the fraction below it (``P`` too large; the rest, above, ``P`` too small),
  and both while the truth accelerates and while it moves straight (below), where a CV filter
  errs in opposite directions (docs/multitarget.md#covariance-consistency-nees).
* **Maneuver flags** (a track with a ``maneuver`` field, or in the CA model): the fraction of
  assigned pairs flagged while the truth target accelerates by at least ``MANEUVER_ACCEL``
  (its acceleration from the velocities of the truth lines around the picture) and while it
  moves straight (below ``STRAIGHT_ACCEL`` over the last ``STRAIGHT_FOR_S`` seconds: a
  windowed detector's flag lingers for a while after a maneuver), and the number of **onsets**
  (a track flagged in a picture and not in its previous one); only when a detector ran (the
  pictures' ``detector`` is not ``"none"``; a file that does not say: when some track is
  flagged), "not applicable" (None) otherwise.
* **Registration by supporting sensors**: the track pictures grouped by their ``sensors``, per
  group how many were assigned and how many false, and the least-squares fit of the assigned
  pairs' x, y errors to ``track − truth ≈ b' + τ v + θ J p`` (:func:`fit`): a sensor with a
  constant bias ``b``, a frame rotated by a small ``θ`` about its site ``s`` or time stamps ``δ``
  late puts a target at ``p`` moving at ``v`` near ``p + b + θ J (p − s) − δ v`` (``J`` the
  rotation by 90°), so the fit gives the offset ``b' = b − θ J s`` [m], the time offset
  ``τ = −δ`` [s] and the rotation ``θ`` about the origin. Its standard errors are the least-squares
  ones from the residual scatter, lower bounds (a track's consecutive pairs are correlated).

Only confirmed tracks are evaluated unless ``all_tracks``.
"""

from __future__ import annotations

from fedtrack.fusion_center.mtt.evaluation.consistency import nees_line, truth_motion
from fedtrack.fusion_center.mtt.evaluation.figures import plot
from fedtrack.fusion_center.mtt.evaluation.metrics import id_changes, set_distance
from fedtrack.fusion_center.mtt.evaluation.scoring import evaluate

__all__ = ["evaluate", "id_changes", "nees_line", "plot", "set_distance", "truth_motion"]

"""The local multi-target tracker's roles, each a pure function over the batched track set
(:mod:`fedtrack.local_filters.mtt.tracker` chains them for a scan): the records they pass
(:mod:`.tracks`), predict and update (:mod:`.filtering`), gate (:mod:`.gating`), confirm and delete
(:mod:`.life`). The associators are :mod:`fedtrack.local_filters.mtt.associators`, the track starts
:mod:`fedtrack.local_filters.mtt.initiation`."""

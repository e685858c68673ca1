"""The multi-target tracker's associators (``[mtt] associator``): ``gnn`` (global nearest
neighbour), ``jipda`` (joint integrated PDA with amplitude and existence), ``mht``
(track-oriented multiple-hypothesis tracking); the interface is ``local_filters/mtt/association.py``."""

"""A multi-target centre's hot standby and failover: the decisions (:mod:`.standby`) and the service's side
of them (:mod:`.service`)."""

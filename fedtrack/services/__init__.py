"""Service processes run by ``fedtrack serve <role>``; shared machinery in :mod:`fedtrack.services.base`."""

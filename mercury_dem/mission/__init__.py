"""The Mission layer: one type every stage takes, whatever the images' source.

A :class:`Mission` owns the catalog, the camera table, the body and the image
reader; a synthetic mission's truth is a separate optional object
(``mission.truth``) that only validation reads. ``synth`` and ``ingest`` write
missions through the same :class:`MissionWriter`.
"""

from mercury_dem.mission.store import Mission, MissionWriter, open_mission, write_image

__all__ = ["Mission", "MissionWriter", "open_mission", "write_image"]

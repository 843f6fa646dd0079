"""A mission stand-in for tests that adjust synthetic network stores: cameras and a-priori poses from the store."""

from __future__ import annotations

from typing import Any

import numpy as np

from mercury_dem.io.synthetic_network_store import BlockedNetwork


class StoredMission:
    """The ``camera``/``a_priori_pose`` part of a mission, answered from a blocked network store's image geometry."""

    def __init__(self, src: BlockedNetwork):
        im = src.images
        self.index = {str(i): k for k, i in enumerate(src.store.image_ids)}
        self.cams, self.ic, self.pos, self.rot = im.cameras, im.image_camera, im.positions, im.rotations

    def camera(self, image_id: str) -> Any:
        return self.cams[self.ic[self.index[image_id]]]

    def a_priori_pose(self, image_id: str) -> tuple[np.ndarray, np.ndarray]:
        k = self.index[image_id]
        return self.pos[k], self.rot[k]

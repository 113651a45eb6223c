"""The event record layout shared by every reader, writer and the tracker: OpenEB's ``EventCD``
(x u16, y u16, p i16, t i64 µs; 16 bytes with padding before t)."""

import numpy as np

EVENT_CD = np.dtype(
    {"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"], "offsets": [0, 2, 4, 8], "itemsize": 16}
)

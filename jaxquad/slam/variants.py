"""The paper's ablation (its Table I) as one switch: which scans, which odometry and which graph
constraints a SLAM run uses.

| variant | scans | odometry of the scans | leg-odometry graph edges |
|---|---|---|---|
| `B` | baseline (the depth image's middle rows, no attitude correction) | depth odometry, leg odometry off (it only gives the first pose) | off |
| `B+LO` | baseline | depth odometry guided and restarted by the leg odometry (`guess+restart`) | preintegrated |
| `B+SS` | stabilized (rows chosen from the IMU's roll and pitch) | depth odometry, leg odometry off | off |
| `full` | stabilized | `guess+restart` | preintegrated |
| `full+level` | level (every pixel's 3D point levelled by roll and pitch, binned by bearing) | `guess+restart` | preintegrated |

Everything else (contact source, SLAM parameters, scan band, range limits) is the same for all.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class Variant:
    scans: str  # jaxquad.estimate.laser.SCAN_KINDS
    odometry: str  # "vo" or "lo"
    vo_coupling: str  # jaxquad.vo.COUPLINGS
    lo_constraints: str  # "off", "velocity" or "preintegrated"


VARIANTS = {
    "B": Variant("baseline", "vo", "off", "off"),
    "B+LO": Variant("baseline", "vo", "guess+restart", "preintegrated"),
    "B+SS": Variant("stabilized", "vo", "off", "off"),
    "full": Variant("stabilized", "vo", "guess+restart", "preintegrated"),
    "full+level": Variant("level", "vo", "guess+restart", "preintegrated"),
}

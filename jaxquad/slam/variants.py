"""The paper's ablation (its Table I) as one switch: which scans, which odometry and which graph
constraints a SLAM run uses.

| variant | scans | odometry of the scans | leg-odometry graph edges |
|---|---|---|---|
| `B` | baseline | depth odometry, leg odometry off | off |
| `B+LO` | baseline | depth odometry, leg odometry `guess+restart` | preintegrated |
| `B+SS` | stabilized | depth odometry, leg odometry off | off |
| `full` | stabilized | depth odometry, leg odometry `guess+restart` | preintegrated |
| `full+level` | level | depth odometry, leg odometry `guess+restart` | preintegrated |

Scans (`jaxquad.estimate.laser.SCAN_KINDS`): baseline takes the depth image's middle rows with no
attitude correction; stabilized chooses the rows from the IMU's roll and pitch; level (ours) levels
every pixel's 3D point by roll and pitch and bins it by bearing. Depth odometry (`jaxquad.vo`) with
the leg odometry off takes only its first pose from it; `guess+restart` starts each alignment from
the leg odometry's motion and restarts a lost frame from its pose.

Everything else (contact source, SLAM parameters, scan band, range limits) is the same for all; the
band's rows are reduced to one range by their minimum, the paper's rule (`jaxquad slam --variant`
and `experiments/ablation.py`; `--band-reduce median` overrides it on the command line).
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

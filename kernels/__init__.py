"""Pure jitted math for one robot: contact observer, leg twist, scan slicing, pose graphs, occupancy
grids. `vmap` at the call site."""
from jaxquad.kernels.contact import ContactEstimate, ContactObserver, ObserverParams, ObserverState
from jaxquad.kernels.occupancy import GridSpec, OccupancyGrid, OccupancyParams, init_grid, insert_scan, map_from_scans
from jaxquad.kernels.posegraph import PoseGraph, SolveInfo, SolverParams, edge_error, optimize
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays, ray_distance
from jaxquad.kernels.scan import CameraIntrinsics, Scan, baseline_scan, level_scan, stabilized_scan
from jaxquad.kernels.twist import Twist, body_twist

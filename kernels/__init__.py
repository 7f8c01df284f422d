"""Pure jitted math for one robot: contact observer, leg twist, scan slicing. `vmap` at the call site."""
from jaxquad.kernels.contact import ContactEstimate, ContactObserver, ObserverParams, ObserverState
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays, ray_distance
from jaxquad.kernels.scan import CameraIntrinsics, Scan, baseline_scan, level_scan, stabilized_scan
from jaxquad.kernels.floor import FloorParams, FloorState, floor_init, floor_step, stance_height
from jaxquad.kernels.robust_twist import RobustTwist, robust_body_twist, robust_weight
from jaxquad.kernels.twist import Twist, body_twist, rolling_contact

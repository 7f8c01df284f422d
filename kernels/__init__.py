"""Pure jitted math for one robot: contact observer, leg twist, scan slicing. `vmap` at the call site."""
from jaxquad.kernels.icp import Alignment, DepthLevel, IcpParams, align, depth_frame, gauss_newton_step
from jaxquad.kernels.contact import ContactEstimate, ContactObserver, ObserverParams, ObserverState
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays, ray_distance
from jaxquad.kernels.scan import CameraIntrinsics, Scan, baseline_scan, level_scan, stabilized_scan
from jaxquad.kernels.twist import Twist, body_twist

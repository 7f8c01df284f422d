"""Pure jitted math for one robot: contact observer, leg twist, scan slicing. `vmap` at the call site."""
from jaxquad.kernels.contact import ContactEstimate, ContactObserver, ObserverParams, ObserverState
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays, ray_distance

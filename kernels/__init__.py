"""Pure jitted math for one robot: contact observer, leg twist, scan slicing. `vmap` at the call site."""

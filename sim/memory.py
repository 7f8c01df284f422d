"""How much memory a fleet chunk needs, and how long a chunk can be on this device.

A chunk's footprint comes from XLA itself: the compiled chunk function's `memory_analysis()`
(arguments + outputs + temporaries - donated aliases). It grows linearly with the chunk length
through the stacked per-sample outputs (depth frames dominate), whose size per camera frame is known
exactly from the output shapes; everything else (the robots' state, the model, one frame's
temporaries) does not depend on the chunk length. Free memory: the accelerator's allocator limit
minus what is in use, or the host's available memory on a CPU.
"""

from __future__ import annotations

import math

import jax

# Share of the free memory a chunk may use: headroom for the allocator's fragmentation and the
# host copies of the previous chunk's outputs.
MEMORY_FRACTION = 0.75
# Share of that budget the planned buffers (state, model, outputs) may take before compiling: the
# rest is for the step's temporaries, which only the compiled chunk's analysis reveals.
PLAN_FRACTION = 0.6
GIB = 2.0**30


def free_bytes(device=None) -> int:
    """Free memory of `device` (the default device): allocator limit minus in use on an
    accelerator, MemAvailable of /proc/meminfo on a CPU."""
    device = jax.devices()[0] if device is None else device
    stats = device.memory_stats() if device.platform != "cpu" else None
    if stats and "bytes_limit" in stats:
        return int(stats["bytes_limit"] - stats.get("bytes_in_use", 0))
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 2**62  # unknown: do not limit


def footprint_bytes(compiled) -> int:
    """Peak bytes one call of a compiled function holds on its device (XLA's memory analysis)."""
    m = compiled.memory_analysis()
    if m is None:
        return 0
    return int(m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes - m.alias_size_in_bytes)


def plan_frames(total_bytes: int, frames: int, out_bytes_per_frame: int, budget: int) -> int:
    """Largest chunk length (camera frames, <= `frames`) whose footprint fits `budget`, given the
    footprint `total_bytes` measured at `frames`; 0 when not even one frame fits."""
    fixed = total_bytes - out_bytes_per_frame * frames
    if out_bytes_per_frame <= 0:
        return frames if total_bytes <= budget else 0
    return max(0, min(frames, math.floor((budget - fixed) / out_bytes_per_frame)))


def largest_fleet(n_robots: int, bytes_at_one_frame: int, budget: int) -> int:
    """Largest robot count whose one-frame chunk fits `budget` (footprints scale with the robots)."""
    per_robot = max(bytes_at_one_frame / max(n_robots, 1), 1.0)
    return int(budget // per_robot)

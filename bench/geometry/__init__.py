"""Pure-numpy geometry core: SE(3)/SO(3) helpers and least-squares fits. Pipeline side: no simulator imports."""

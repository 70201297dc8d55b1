"""Level of detail without Qt or GL: the `ViewState` a frame is selected for, culling, index
variants, the `RenderSet` a provider returns, and the quadtree traversal providers steer.

Everything here is numpy on the CPU; `globeview.render` turns a render set into draw calls.
"""

"""bentray media meshes: uniform box, stratified slabs, adaptive tetrahedra."""

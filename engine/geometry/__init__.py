"""What rays meet: primitives and triangles, BVHs, exact CSG (`csg`) and the cyclic
scene graph of L-systems (`dcsg`), the scene's trace layout (`assembly`), and ray
casting through all of them (`raycast`). Imports engine.core and engine.lsystem."""

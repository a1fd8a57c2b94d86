// liver_20k.msh: liver2.obj's surface (SOFA, decimetres) remeshed and tetrahedralised by Gmsh
// 4.8.4, graded: 1.7 mm elements on the right lobe's tip (obj x > 0.39, the world's x > 6.5 cm
// once liver_grasp_20k.yaml places it: where the grasper closes), growing over 2 cm to 7 mm
// elsewhere, and to 7 mm from 1.2 cm under the surface. Run by remesh_liver_20k.sh, which first
// writes liver2.obj as the liver2.stl this file merges. Deterministic: the same Gmsh gives the
// same file.
Merge "liver2.stl";
// one parametrisable patch per smooth part of the surface (facets within 40 deg), then a
// geometry whose surfaces Gmsh can remesh
ClassifySurfaces{40 * Pi / 180, 1, 1, Pi};
CreateGeometry;
Surface Loop(1) = Surface{:};
Volume(1) = {1};
Physical Volume(1) = {1};   // write the tetrahedra only

Field[1] = Box;             // fine on the lobe's tip, 2 cm transition
Field[1].VIn = 0.017;
Field[1].VOut = 0.07;
Field[1].XMin = 0.39; Field[1].XMax = 1.0;
Field[1].YMin = -2; Field[1].YMax = 2;
Field[1].ZMin = 10; Field[1].ZMax = 20;
Field[1].Thickness = 0.2;
Field[2] = Distance;        // distance to the surface
Field[2].SurfacesList = {Surface{:}};
Field[3] = Threshold;       // fine only near the surface: coarser inside
Field[3].InField = 2;
Field[3].SizeMin = 0.017;
Field[3].SizeMax = 0.07;
Field[3].DistMin = 0.01;
Field[3].DistMax = 0.12;
Field[4] = Max;
Field[4].FieldsList = {1, 3};
Background Field = 4;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
Mesh.Algorithm = 6;          // Frontal-Delaunay surfaces
Mesh.Algorithm3D = 1;        // Delaunay volume
Mesh.Optimize = 1;           // remove ill-shaped tets: gamma below 0.5 is optimised
Mesh.OptimizeThreshold = 0.5;
Mesh.MshFileVersion = 2.2;

// A hemisphere of radius 20 mm, in metres: the flat back on z = 0, the apex at (0, 0, 0.02).
// For the Hertz test of two soft domes pressed apex to apex (tests/unit/pipeline/
// hertz_contact_test.cpp): tetrahedra of h0 at the apex, where the contact patch is, growing by
// `growth` per unit of distance from it, up to 5 mm. Physical groups: "back" (the flat face) and
// "body" (the volume). `gmsh -3 hemisphere.geo -o hemisphere.msh` (-setnumber h0 0.0003 for finer).
SetFactory("OpenCASCADE");
DefineConstant[ h0 = 0.0004, growth = 0.25 ];
R = 0.02;
Sphere(1) = {0, 0, 0, R, 0, Pi/2, 2*Pi};
Field[1] = MathEval;
Field[1].F = Sprintf("Min(%g + %g * Sqrt(x^2 + y^2 + (z - %g)^2), 0.005)", h0, growth, R);
Background Field = 1;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
Mesh.Optimize = 1;
Mesh.MshFileVersion = 2.2;
Physical Surface("back") = Surface In BoundingBox{-1, -1, -1e-6, 1, 1, 1e-6};
Physical Volume("body") = {1};

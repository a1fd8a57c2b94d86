// An ellipsoidal stand-in for a stomach under the liver's right lobe (Tactus scenes/meshes):
// semi-axes 50 x 50 x 25 mm, centred at the origin, in metres; tetrahedra of about 8 mm.
SetFactory("OpenCASCADE");
Sphere(1) = {0, 0, 0, 1};
Dilate {{0, 0, 0}, {0.05, 0.05, 0.025}} { Volume{1}; }
Mesh.CharacteristicLengthMin = 0.006;
Mesh.CharacteristicLengthMax = 0.008;
Mesh.MshFileVersion = 2.2;

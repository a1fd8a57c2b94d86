// A 4 x 3 x 2 cm box with physical groups: its base and top faces, one unnamed side face (tag 7),
// and the volume. Regenerate: gmsh -3 box_groups.geo -format msh41 -o box_groups.msh
lc = 0.01;
Point(1) = {0, 0, 0, lc};
Point(2) = {0.04, 0, 0, lc};
Point(3) = {0.04, 0.03, 0, lc};
Point(4) = {0, 0.03, 0, lc};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
out[] = Extrude {0, 0, 0.02} { Surface{1}; };
// out[0]: top, out[1]: the volume, out[2..5]: the sides from lines 1..4 (y = 0, x = 0.04,
// y = 0.03, x = 0)
Physical Surface("base") = {1};
Physical Surface("top") = {out[0]};
Physical Surface(7) = {out[5]};
Physical Volume("body") = {out[1]};

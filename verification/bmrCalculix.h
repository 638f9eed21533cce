// CalculiX (ccx) harness: independent implicit reference solutions for the
// verification tests and the benchmark driver.
//
// A bmr::Model (mm, Pa, N) is written as a CalculiX input deck in the
// consistent mm-N-s-tonne system (moduli in MPa = N/mm^2):
//   each material's law as its CalculiX card (bmrMaterialLaw.h): neo-Hookean
//   W = mu/2 (I1bar - 3) + kappa/2 (J - 1)^2 -> *HYPERELASTIC, NEO HOOKE with
//   C10 = mu/2, D1 = 2/kappa; Mooney-Rivlin -> *HYPERELASTIC, MOONEY-RIVLIN
//   with C10, C01, D1.
// Tetrahedra become quadratic C3D10 elements (mid-edge nodes added at the
// straight edge midpoints and shared between neighbours) or linear C3D4;
// hexahedra become C3D20R (quadratic) or C3D8 (linear). A node set's
// constraint covers the boundary faces (triangles; a quadrilateral as two)
// whose vertices are all constrained in that component; a mid-edge node on an
// edge of such a face gets the constraint, with the mean of its two end
// values, which is the linear element's boundary condition along that edge.
// Other mid-edge nodes stay free, e.g. on an edge between two constrained
// surface nodes that cuts through the interior.
// A rigid contact surface becomes frictionless node-to-face penalty contact:
// its triangles are the faces of a fixed layer of wedges outside the body
// (master); the body's boundary faces whose corners are all slave nodes are
// the slave, as element faces (a nodal slave surface gets the wrong penalty
// area, docs/registration.md). Face-to-face contact did not converge on
// Colin27 (docs/registration.md).
// The static step is geometrically nonlinear (NLGEOM); loads are ramped
// linearly over the step (the end state of a hyperelastic solid does not depend
// on the path). CalculixSettings::startDisplacements adds steps that hold the
// boundary at a given state and then release it (continuation);
// CalculixSettings::stabilisationStiffness adds proximal steps instead, and
// stabilisationExtrapolations restarts them from their extrapolated limit.
// bmrCalculixDeck.cxx writes the deck; bmrCalculix.cxx runs ccx and reads it.
// Displacements and reaction forces are read back from the .dat file
// (*NODE PRINT).
#ifndef bmrCalculix_h
#define bmrCalculix_h

#include "bmrMeshGenerators.h"
#include "bmrModel.h"

#include <array>
#include <iosfwd>
#include <string>
#include <vector>

namespace bmr
{

struct CalculixSettings
{
  /** true: C3D10 tetrahedra and C3D20R hexahedra (mid-edge nodes added);
   *  false: C3D4 and C3D8. */
  bool quadratic = true;
  /** Overrides of the CalculiX element type names (empty: the defaults above),
   *  e.g. "C3D8I" or "C3D20" for hexahedra. Must match the node count. */
  std::string tetrahedronType;
  std::string hexahedronType;

  /** Initial increment as a fraction of the step (the step runs from 0 to 1). */
  double initialIncrement = 0.1;
  double minimumIncrement = 1e-6;
  int    maximumIncrements = 1000;
  /** Newton convergence: residual force relative to the mean force (CalculiX
   *  default 0.005) and displacement correction relative to the increment
   *  (default 0.01). Tighter values cost one more Newton iteration or so. */
  double residualTolerance = 1e-5;
  double correctionTolerance = 1e-4;

  /** Frictionless contact with the model's rigid contact surfaces (penalty
   *  contact): the slope of the linear pressure-overclosure law (MPa per mm
   *  of overlap). 0: 10 times the stiffest material's Young's modulus per
   *  mean edge length of the slave faces, which keeps the overlap near 10 %
   *  of an edge at contact pressures of the size of E. */
  double contactStiffness = 0.0;
  /** true: CalculiX pairs each slave node with a master face once per
   *  increment (SMALL SLIDING) instead of at every Newton iteration below the
   *  ninth. On Colin27 a mid-edge slave switched faces from one iteration to
   *  the next, so each increment converged only once CalculiX froze the
   *  pairing at the ninth (docs/registration.md). */
  bool smallSliding = false;

  /** Continuation from a given state: per model node, displacements (mm).
   *  Non-empty: a first step holds the corner nodes of the body's boundary
   *  triangles at these displacements in the components the model leaves
   *  free (mid-edge nodes stay free: on a curved contact surface the mean of
   *  two corners can lie beyond it), under the model's loads, constraints
   *  and contact; a second step releases them (OP=NEW), so that the result
   *  is CalculiX's own equilibrium, reached from near the given state. For contact that Newton does not find from the reference
   *  state, e.g. a brain settling onto the skull through 10 Pa CSF. */
  std::vector<Vector3> startDisplacements;
  /** With startDisplacements: release the held nodes gradually. RunCalculix
   *  then runs the hold step alone first, and then hold and release with the
   *  hold's reaction forces applied at the held nodes as loads that fall
   *  linearly to zero over the release step: the release starts in
   *  equilibrium and Newton follows the body as it lets go, where a release
   *  at once (false) leaves Newton the whole out-of-balance at the first
   *  iteration (on Colin27 a first correction of 55 mm, docs/registration.md).
   *  With a stabilisation the same for the loading step's springs, which the
   *  first proximal step releases: a run of the loading step alone gives
   *  their forces, -k u at each sprung node, and the first proximal step
   *  applies them as loads falling linearly to zero (on Colin27's 20 mm
   *  scene that step diverged at every increment size without it). */
  bool gradualRelease = false;
  /** What gradualRelease sets for each run (or a caller with its own forces):
   *  stop after the first step (the hold, or the stabilisation's loading
   *  step); and per mesh node, forces (N) applied at the held (sprung)
   *  components in the release (first proximal) step, falling linearly to
   *  zero over it (empty: none). */
  bool                 holdOnly = false;
  std::vector<Vector3> releaseForces;

  /** Proximal stabilisation, for a body whose surface floats in soft tissue
   *  (Colin27's 10 Pa CSF) and on which Newton diverges as soon as slaves lift
   *  off the contact surface (docs/registration.md, "A truth from CalculiX").
   *  stabilisationStiffness > 0 (N/mm) ties each corner node of the body's
   *  boundary, in the components the model leaves free, by springs of this
   *  stiffness to an anchor: the first step anchors them at the reference
   *  state, each of the stabilisationSteps steps after it at where the step
   *  before ended. Each step thus solves equilibrium plus k (u - u_before) at
   *  those nodes (a proximal-point iteration); its fixed point is CalculiX's
   *  own equilibrium, and what the springs still carry at the end is
   *  CalculixResult::stabilisationForces.back(). Two anchor sets take turns:
   *  the free one follows its nodes, *BOUNDARY, FIXED then freezes it there.
   *  Not with startDisplacements (the other way in).
   *  A mode of stiffness lambda (per node) contracts by k / (k + lambda) a
   *  step: stiff springs hold Newton but converge slowly on the softest modes
   *  (Colin27's brain drifting in its CSF: about 0.8 a step at 3e-4 N/mm). So
   *  after stabilisationSteps steps the springs can be replaced by softer ones,
   *  stabilisationSoftening times softer each stage, stabilisationStages stages
   *  in all (stabilisationSteps each; each stage's springs anchored where the
   *  stage before ended). */
  double stabilisationStiffness = 0.0;
  int    stabilisationSteps = 0;
  int    stabilisationStages = 1;
  double stabilisationSoftening = 10.0;
  /** Restarts of the proximal iteration from its extrapolated limit (needs
   *  at least 2 stabilisationSteps). The slowest mode dominates the steps'
   *  motions d_k after a few steps, so that they shrink geometrically, by r a
   *  step; RunCalculix measures r = <d_n, d_n-1> / |d_n-1|^2 over the body's
   *  nodes from a run's last two steps and runs the whole deck again with the
   *  first proximal step's anchors at u_n + r / (1 - r) d_n, where that
   *  geometric sequence ends (r capped at kMaxExtrapolationRatio). The fixed
   *  point does not depend on where the anchors stand, so the result is
   *  still CalculiX's own equilibrium; that step's spring force measures how
   *  far the extrapolation missed. A restart that fails leaves the run
   *  before it as the result (CalculixResult::stabilisationStopped says so). */
  int stabilisationExtrapolations = 0;
  /** Per CalculiX mesh node (mm): where the first proximal step's anchors
   *  stand (empty: where the loading step left the nodes). What
   *  stabilisationExtrapolations sets for each restart. */
  std::vector<Vector3> stabilisationAnchorStart;

  /** Equation solver (*STATIC, SOLVER=...): empty for CalculiX's default
   *  (SPOOLES in Debian's build), or "ITERATIVE CHOLESKY", "ITERATIVE SCALING". */
  std::string solver;

  /** Threads for CalculiX (OMP_NUM_THREADS, CCX_NPROC_*); 0: leave the environment. */
  int threads = 0;
  /** ccx executable; empty: $BMR_CCX, then `ccx` on PATH. */
  std::string executable;
  /** Folder for the job; empty: a fresh folder under the system temp folder,
   *  removed afterwards unless keepFiles. */
  std::string workDirectory;
  bool        keepFiles = false;
  std::string jobName = "bmr";
};

/** The mesh actually given to CalculiX: the model's nodes first (same
 *  indices), then the mid-edge nodes of quadratic elements. */
struct CalculixMesh
{
  std::vector<Vector3>               nodes;      // mm
  Index                              modelNodes = 0;
  std::vector<std::array<Index, 2>>  edgeParents; // for node modelNodes + i: its edge's end nodes
  std::vector<std::string>           elementTypes; // per model cell
  std::vector<std::vector<Index>>    elements;     // per model cell, CalculiX node order, 0-based
  /** The model's boundary triangles and the mid-edge nodes of their edges
   *  (k -> k+1), -1 where the edge is no element edge (a quad's diagonal) or
   *  the elements are linear. */
  std::vector<std::array<Index, 3>>  boundaryTriangles;
  std::vector<std::array<Index, 3>>  boundaryTriangleMidNodes;

  /** Per contact surface of the model: the rigid master, a layer of C3D6
   *  wedges (all nodes fixed) built outward from the surface's triangles, so
   *  that each wedge's face S1 is a triangle of the surface facing the body;
   *  and the slave faces (model cell, CalculiX face number 1...) of the
   *  body's boundary whose corners all are slave nodes. The wedges' nodes
   *  follow the mid-edge nodes (from firstRigidNode on). */
  struct ContactPair
  {
    std::vector<std::array<Index, 6>>    masterWedges;
    std::vector<std::pair<Index, int>>   slaveFaces;
    double                               slaveMeanEdge = 0.0; // mm
  };
  std::vector<ContactPair> contactPairs;
  Index                    firstRigidNode = 0;

  /** Mask over the mesh nodes for a set of model nodes (a mask over model
   *  nodes): the set's nodes and the mid-edge nodes on the edges of boundary
   *  triangles whose three vertices are all in the set. */
  std::vector<char> MeshNodeMask(const std::vector<char> & modelMask) const;
};

/** Mid-edge nodes and CalculiX connectivity for a model (no file written).
 *  Throws bmr::Error for quadratic elements on a mixed hexahedron/tetrahedron
 *  model (they would not conform at the interface). */
CalculixMesh
MakeCalculixMesh(const Model & model, const CalculixSettings & settings = {});

/** Writes the input deck. Throws bmr::Error for what the deck cannot express
 *  (a CSF fluid surface). */
void
WriteCalculixDeck(std::ostream & stream, const Model & model, const CalculixMesh & mesh, const CalculixSettings & settings = {});

struct CalculixResult
{
  CalculixMesh         mesh;
  std::vector<Vector3> meshDisplacements;   // mm, every mesh node (mid-edge nodes included)
  std::vector<Vector3> meshReactionForces;  // N, every mesh node (residual-size at free nodes)
  std::vector<Vector3> displacements;       // mm, the model's nodes only
  double               wallSeconds = 0.0;   // the ccx run
  int                  increments = 0;      // converged increments, all steps
  int                  iterations = 0;      // Newton iterations, all steps
  int                  lastStepIncrements = 0; // of the last step (the release, with startDisplacements)
  int                  lastStepIterations = 0;
  double               holdRunSeconds = 0.0;   // gradualRelease: the first run (the hold alone), not in wallSeconds
  /** With stabilisation: per step, the largest force (N) a node's springs
   *  carry at its end, k |u_step - u_step before| (the first step's against
   *  the reference state), and that k (N/mm). The last force is the
   *  out-of-balance left in the result. */
  std::vector<double>  stabilisationForces;
  std::vector<double>  stabilisationStiffnesses;
  /** Non-empty when CalculiX stopped in a proximal step after the first (no
   *  Newton convergence, e.g. penalty contact flipping between iterations):
   *  what it said; the result is then the last finished step's (its reaction
   *  forces zero), whose springs' force is stabilisationForces.back(). */
  std::string          stabilisationStopped;
  /** Stabilised runs: the mesh displacements at the ends of the (up to) two
   *  steps before the result's, older first; the result minus the last of
   *  them is the last step's motion. */
  std::vector<std::vector<Vector3>> stabilisationStepsBefore;
  /** stabilisationExtrapolations: per restart, the contraction r measured
   *  on the run before, the largest anchor shift r / (1 - r) |d_n| (mm),
   *  and the index in stabilisationForces of the restart's first proximal
   *  step (the one anchored there). */
  struct Extrapolation
  {
    double      ratio = 0.0;
    double      largestShift = 0.0;
    std::size_t firstStep = 0;
  };
  std::vector<Extrapolation> stabilisationExtrapolations;
  std::string          workDirectory;       // kept only with keepFiles

  /** Sum of reaction forces (N) over the given model nodes and the mid-edge
   *  nodes of boundary triangles whose three corners are all in the set. */
  Vector3 TotalReactionForce(const std::vector<Index> & modelNodes) const;
};

/** Path of the ccx executable (settings.executable, $BMR_CCX, or `ccx` on
 *  PATH), or empty if none is found. */
std::string
FindCalculix(const std::string & executable = {});

/** The largest contraction a restart extrapolates with (a factor
 *  r / (1 - r) = 9 on the last step's motion): beyond it the sequence is
 *  not yet geometric enough to trust its tail. */
constexpr double kMaxExtrapolationRatio = 0.9;

/** Writes the deck, runs ccx, reads the results. Throws bmr::Error when ccx is
 *  missing, fails, or does not complete the step (with the tail of its output). */
CalculixResult
RunCalculix(const Model & model, const CalculixSettings & settings = {});

/** For each point, the index of the node at the same position (within
 *  `tolerance`, mm), or -1. Hash-grid lookup, O(n). */
std::vector<Index>
MatchNodes(const std::vector<Vector3> & points, const std::vector<Vector3> & nodes, double tolerance = 1e-6);

/** Displacement difference at the points of `nodes` that are also reference
 *  nodes (MatchNodes); throws bmr::Error if some node has no partner. */
struct DisplacementComparison
{
  int    nodes = 0;
  double rmsError = 0.0; // mm, root mean square of |u - u_ref| over the nodes
  double maxError = 0.0; // mm
  Index  maxNode = -1;   // index into `nodes` where the largest error occurs
};

DisplacementComparison
CompareDisplacements(const std::vector<Vector3> & nodes,
                     const std::vector<Vector3> & displacements,
                     const std::vector<Vector3> & referenceNodes,
                     const std::vector<Vector3> & referenceDisplacements,
                     double                       tolerance = 1e-6);

/** Block indentation, the CalculiX-referenced non-homogeneous verification
 *  case: a block [0,size] with its bottom face (z = 0) fixed, and the top-face
 *  nodes inside the centred square patch |x - cx|, |y - cy| <= patchHalfWidth
 *  given the displacement (0, 0, -depth) in all components. Node sets "bottom",
 *  "patch" (plus the block's sets). Choose divisions so that the patch edges
 *  fall on grid lines, then every resolution loads the same region. */
struct IndentationProblem
{
  Vector3  size{ 20.0, 20.0, 10.0 }; // mm
  double   patchHalfWidth = 5.0;     // mm
  double   depth = 2.0;              // mm
  Material material{ "tissue", 3000.0, 0.45, 1000.0 };
};

Model
MakeIndentationModel(const IndentationProblem & problem, const std::array<int, 3> & divisions, GridCells cells);

/** The same continuum problem on the quarter x >= cx, y >= cy of the block
 *  (block, patch and material are symmetric about x = cx and y = cy), with
 *  symmetry conditions u_x = 0 on x = cx (set "xmin") and u_y = 0 on y = cy
 *  (set "ymin"): a reference solution at a quarter of the cost. `divisions`
 *  are the quarter's; the full-block reaction force is 4x the quarter's. */
Model
MakeIndentationQuarterModel(const IndentationProblem & problem, const std::array<int, 3> & divisions, GridCells cells);

/** A brain-like case for comparing with CalculiX: the brain-sized ellipsoid
 *  (semi-axes 70, 85, 60 mm), its surface at or below the body grid's node
 *  plane nearest z = baseZ held (a grid plane, so that every subdivision holds
 *  the same part of the surface), and the surface
 *  nodes within craniotomyRadius of the top (0, 0, 60) sagging by
 *  depth (1 - (r / R)^2) along -z (all components prescribed; zero at the rim,
 *  so the solution has no rim singularity and a refinement study converges).
 *  Node sets "surface", "base", "craniotomy". */
struct BrainSagProblem
{
  Vector3  semiAxes{ 70.0, 85.0, 60.0 }; // mm
  double   baseZ = -45.0;                // mm, rounded to the body grid's nearest node plane
  double   craniotomyRadius = 25.0;      // mm
  double   depth = 10.0;                 // mm
  Material material{ "brain", 3000.0, 0.49, 1000.0 };
};

/** The body is the ellipsoid's grid cells of `bodySpacing` (MakeEllipsoidMesh),
 *  each split into subdivisions^3 cells of 6 tetrahedra: meshes of one body
 *  spacing bound the same body at every subdivision and their nodes nest.
 *  `quarter`: the part x, y >= 0 with symmetry conditions u_x = 0 on x = 0
 *  (set "xmin") and u_y = 0 on y = 0 ("ymin"); body, supports and load are
 *  symmetric about both planes (the Kuhn tetrahedra are not, which a
 *  reference may ignore). Throws bmr::Error when the grid has no node plane
 *  at x = 0 or y = 0 (choose a body spacing or an even subdivision that has). */
Model
MakeBrainSagModel(const BrainSagProblem & problem, double bodySpacing, int subdivisions, bool quarter = false);

/** Full-model displacements at `points` from the solution on the quarter
 *  x >= mirrorX, y >= mirrorY of a model symmetric about both planes, by
 *  reflection: u(p) = S u(S p) with S the reflection that brings p into the
 *  quarter. Throws bmr::Error if a reflected point is not a quarter node. */
std::vector<Vector3>
UnfoldQuarterDisplacements(double                       mirrorX,
                           double                       mirrorY,
                           const std::vector<Vector3> & quarterNodes,
                           const std::vector<Vector3> & quarterDisplacements,
                           const std::vector<Vector3> & points,
                           double                       tolerance = 1e-6);

/** The same for the indentation block (mirrored about its mid-planes). */
std::vector<Vector3>
UnfoldQuarterDisplacements(const IndentationProblem &   problem,
                           const std::vector<Vector3> & quarterNodes,
                           const std::vector<Vector3> & quarterDisplacements,
                           const std::vector<Vector3> & points,
                           double                       tolerance = 1e-6);

} // namespace bmr

#endif

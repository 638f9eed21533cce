// The constitutive laws a Material can take, and the one place each is named:
// scenes ("law"), mesh files (the "material_law" array), Python
// (Material(law=...)), the solve's components, the CalculiX deck and the
// docs (docs/materials.md) all read MaterialLaws(). Plain C++17.
//
// Every law shares the volumetric term kappa/2 (J - 1)^2 and the collapse
// barrier (src/mechanics/materials/bmrCollapseBarrier.h); E and nu give the
// small-strain shear modulus mu and kappa for all of them, so the stable time
// step and dynamic relaxation's masses do not depend on the law.
//   neo-hookean    W = mu/2 (I1bar - 3)
//   mooney-rivlin  W = C10 (I1bar - 3) + C01 (I2bar - 3),
//                  C10 = (1 - s) mu / 2, C01 = s mu / 2, s = secondInvariantShare in [0, 1]
// The kernels' forms live in src/mechanics/materials/, one law per file.
#ifndef bmrMaterialLaw_h
#define bmrMaterialLaw_h

#include <cstdint>
#include <string>
#include <vector>

namespace bmr
{

struct Material;

enum class MaterialLaw : std::uint8_t
{
  NeoHookean = 0,
  MooneyRivlin = 1
};

struct MaterialLawDescription
{
  MaterialLaw  law;
  const char * name;            // in scenes, mesh files, Python and reports
  const char * formula;         // the isochoric strain energy, for messages and docs
  const char * calculixKeyword; // the CalculiX (and Abaqus) card of the same law
  bool         secondInvariant; // has the second invariant's term (takes Material::secondInvariantShare)
};

/** A parameter a law takes beside E, nu and the density: a member of
 *  Material, named once here for every carrier (a scene material's key and
 *  "material_fields" array, the mesh files' array beside "material_law",
 *  Python's Material keyword and attribute, model bundles, the
 *  precomputation's key, the material mapping's mixture). A law that does
 *  not take it has its neutral value. */
struct MaterialParameter
{
  const char * name;
  double Material::*value;
  double       neutral;
  const char * meaning; // for messages and help
};

/** Every law's parameters, each once, in the order files store them. */
const std::vector<MaterialParameter> &
MaterialParameters();

/** E, nu, the density, the law's code and every parameter, in that order:
 *  two materials with equal keys behave the same (the name aside). */
std::vector<double>
MaterialKey(const Material & material);

/** Every law, in the order of its numeric code (the mesh files' "material_law"). */
const std::vector<MaterialLawDescription> &
MaterialLaws();

const MaterialLawDescription &
DescribeMaterialLaw(MaterialLaw law);

/** The law of this name; bmr::Error naming the known laws otherwise. */
MaterialLaw
MaterialLawNamed(const std::string & name);

/** The law of this numeric code (mesh files); bmr::Error otherwise. */
MaterialLaw
MaterialLawOfCode(double code);

/** {"neo-hookean", "mooney-rivlin"}: the names in code order. */
std::vector<std::string>
MaterialLawNameList();

/** "neo-hookean, mooney-rivlin". */
std::string
MaterialLawNames();

/** Empty when the material's law parameters are valid, else what is wrong
 *  and what to do (E and nu are checked by the model, not here). */
std::string
MaterialLawProblem(const Material & material);

/** The constants of the material's CalculiX card (calculixKeyword) in the
 *  deck's units (MPa): C10, D1 (neo-Hookean) or C10, C01, D1 (Mooney-Rivlin),
 *  D1 = 2 / kappa. */
std::vector<double>
CalculixMaterialConstants(const Material & material);

} // namespace bmr

#endif

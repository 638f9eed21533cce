// The laws' names and parameters (src/mechanics/include/bmrMaterialLaw.h): the one table
// that scenes, mesh files, Python, reports and the CalculiX deck read.
#include "bmrMaterialLaw.h"

#include "bmrModel.h"
#include "bmrUnits.h"

#include <cmath>
#include <sstream>

namespace bmr
{

const std::vector<MaterialParameter> &
MaterialParameters()
{
  static const std::vector<MaterialParameter> parameters{
    { "second_invariant_share", &Material::secondInvariantShare, 0.0,
      "Mooney-Rivlin's C01 / (C10 + C01), the share of the small-strain shear modulus carried by the second "
      "invariant, in [0, 1]" },
  };
  return parameters;
}

std::vector<double>
MaterialKey(const Material & material)
{
  std::vector<double> key{ material.youngsModulus, material.poissonRatio, material.density,
                           static_cast<double>(material.law) };
  for (const MaterialParameter & parameter : MaterialParameters())
  {
    key.push_back(material.*parameter.value);
  }
  return key;
}

double
Material::SecondInvariantModulus() const
{
  return DescribeMaterialLaw(law).secondInvariant ? secondInvariantShare * ShearModulus() : 0.0;
}

const std::vector<MaterialLawDescription> &
MaterialLaws()
{
  static const std::vector<MaterialLawDescription> laws{
    { MaterialLaw::NeoHookean, "neo-hookean", "mu/2 (I1bar - 3)", "*HYPERELASTIC, NEO HOOKE", false },
    { MaterialLaw::MooneyRivlin, "mooney-rivlin", "C10 (I1bar - 3) + C01 (I2bar - 3)", "*HYPERELASTIC, MOONEY-RIVLIN",
      true },
  };
  return laws;
}

const MaterialLawDescription &
DescribeMaterialLaw(MaterialLaw law)
{
  for (const MaterialLawDescription & description : MaterialLaws())
  {
    if (description.law == law)
    {
      return description;
    }
  }
  throw Error("material law code " + std::to_string(static_cast<int>(law)) + " is not one of " + MaterialLawNames() +
              " (internal error; please report it).");
}

std::vector<std::string>
MaterialLawNameList()
{
  std::vector<std::string> names;
  for (const MaterialLawDescription & description : MaterialLaws())
  {
    names.push_back(description.name);
  }
  return names;
}

std::string
MaterialLawNames()
{
  std::string names;
  for (const std::string & name : MaterialLawNameList())
  {
    names += (names.empty() ? "" : ", ") + name;
  }
  return names;
}

MaterialLaw
MaterialLawNamed(const std::string & name)
{
  for (const MaterialLawDescription & description : MaterialLaws())
  {
    if (name == description.name)
    {
      return description.law;
    }
  }
  throw Error("unknown material law '" + name + "'; the laws are " + MaterialLawNames() + ".");
}

MaterialLaw
MaterialLawOfCode(double code)
{
  for (const MaterialLawDescription & description : MaterialLaws())
  {
    if (code == static_cast<double>(description.law))
    {
      return description.law;
    }
  }
  std::ostringstream message;
  message << "material law code " << code << " is not one of the laws' codes (";
  for (const MaterialLawDescription & description : MaterialLaws())
  {
    message << (description.law == MaterialLaw::NeoHookean ? "" : ", ") << static_cast<int>(description.law) << " "
            << description.name;
  }
  message << ").";
  throw Error(message.str());
}

std::string
MaterialLawProblem(const Material & material)
{
  const MaterialLawDescription & description = DescribeMaterialLaw(material.law);
  std::ostringstream             problem;
  if (!description.secondInvariant && material.secondInvariantShare != 0.0)
  {
    problem << "has a second-invariant share of " << material.secondInvariantShare << " but the " << description.name
            << " law has none; set the law to mooney-rivlin or the share to 0";
  }
  else if (description.secondInvariant &&
           !(material.secondInvariantShare >= 0.0 && material.secondInvariantShare <= 1.0))
  {
    problem << "has a second-invariant share (C01 / (C10 + C01)) of " << material.secondInvariantShare
            << "; it must lie in [0, 1] (C10, C01 >= 0 keep the law stable)";
  }
  return problem.str();
}

std::vector<double>
CalculixMaterialConstants(const Material & material)
{
  const double mu = material.ShearModulus() * units::PascalToInternal;
  const double secondModulus = material.SecondInvariantModulus() * units::PascalToInternal;
  const double D1 = 2.0 / (material.BulkModulus() * units::PascalToInternal);
  if (DescribeMaterialLaw(material.law).secondInvariant)
  {
    return { 0.5 * (mu - secondModulus), 0.5 * secondModulus, D1 };
  }
  return { 0.5 * mu, D1 };
}

} // namespace bmr

#include "bmrSettingsTable.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>

namespace bmr
{

std::string
SettingNumberText(double value)
{
  if (value == std::floor(value) && std::abs(value) < 1e15)
  {
    return std::to_string(static_cast<long long>(value));
  }
  for (int digits = 1; digits <= 17; ++digits)
  {
    std::ostringstream text;
    text.precision(digits);
    text << value;
    if (std::strtod(text.str().c_str(), nullptr) == value)
    {
      return text.str();
    }
  }
  return std::to_string(value);
}

std::string
SettingFieldBase::Range() const
{
  switch (kind)
  {
    case Kind::Flag:
      return "true or false";
    case Kind::Text:
      return "";
    case Kind::Choice:
    {
      std::string text;
      for (const std::string & choice : choices)
      {
        text += (text.empty() ? "\"" : ", \"") + choice + "\"";
      }
      return text;
    }
    default:
      break;
  }
  const bool bounded = std::isfinite(highest) && (kind != Kind::Integer || highest < std::numeric_limits<int>::max());
  if (std::isfinite(lowest) && bounded)
  {
    return (kind == Kind::Integer ? "integer in " : "") + std::string(lowestOpen ? "(" : "[") +
           SettingNumberText(lowest) + ", " + SettingNumberText(highest) + (highestOpen ? ")" : "]");
  }
  if (std::isfinite(lowest))
  {
    return (kind == Kind::Integer ? "integer " : "") + std::string(lowestOpen ? "> " : ">= ") +
           SettingNumberText(lowest);
  }
  return kind == Kind::Integer ? "integer" : "";
}

std::string
SettingFieldBase::Check(double value) const
{
  const std::string got = ", got " + SettingNumberText(value);
  switch (kind)
  {
    case Kind::Flag:
      return value == 0.0 || value == 1.0 ? "" : "must be true or false" + got;
    case Kind::Choice:
      return value >= 0.0 && value < static_cast<double>(choices.size()) && value == std::floor(value)
               ? ""
               : "must be one of " + Range();
    case Kind::Text:
      return "";
    default:
      break;
  }
  if (!std::isfinite(value))
  {
    return "must be a finite number" + got;
  }
  if (kind == Kind::Integer && value != std::floor(value))
  {
    return "must be an integer" + got;
  }
  const bool aboveLowest = lowestOpen ? value > lowest : value >= lowest;
  const bool belowHighest = highestOpen ? value < highest : value <= highest;
  return aboveLowest && belowHighest ? "" : "must be " + Range() + got;
}

double
SettingFieldBase::Parse(const std::string & text) const
{
  double value = 0.0;
  switch (kind)
  {
    case Kind::Flag:
      if (text != "true" && text != "false" && text != "1" && text != "0")
      {
        throw Error("setting '" + name + "' must be true or false, got '" + text + "'");
      }
      value = text == "true" || text == "1" ? 1.0 : 0.0;
      break;
    case Kind::Choice:
    {
      const auto found = std::find(choices.begin(), choices.end(), text);
      if (found == choices.end())
      {
        throw Error("setting '" + name + "' must be one of " + Range() + ", got '" + text + "'");
      }
      value = static_cast<double>(found - choices.begin());
      break;
    }
    case Kind::Text:
      throw Error("setting '" + name + "' is text, not a value to parse");
    default:
    {
      char * end = nullptr;
      value = std::strtod(text.c_str(), &end);
      if (text.empty() || end == text.c_str() || *end != '\0')
      {
        throw Error("setting '" + name + "' must be a number, got '" + text + "'");
      }
    }
  }
  if (const std::string problem = Check(value); !problem.empty())
  {
    throw Error("setting '" + name + "' " + problem);
  }
  return value;
}

std::string
SettingFieldBase::OptionName() const
{
  std::string option = "--" + name;
  std::replace(option.begin(), option.end(), '_', '-');
  return option;
}

} // namespace bmr

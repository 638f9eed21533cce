// Settings as tables: a row per setting with its name, type, unit, range,
// meaning and accessors, so that every face (scene file, command line,
// Python, docs) reads one vocabulary. bmrSolverSettingsTable.h holds the
// solver's rows, bmrBrainShiftRegistration.h the registration's.
#ifndef bmrSettingsTable_h
#define bmrSettingsTable_h

#include "bmrError.h"

#include <functional>
#include <limits>
#include <string>
#include <vector>

namespace bmr
{

/** What every row has, whatever settings it belongs to. */
struct SettingFieldBase
{
  enum class Kind
  {
    Number,
    Integer,
    Flag,
    Choice,
    Text
  };

  std::string name; // snake_case: scene key, Python name; the command line's --name-with-dashes
  Kind        kind = Kind::Number;
  std::string unit; // empty: dimensionless
  std::string meaning;
  /** Which part of a larger whole the setting belongs to (e.g. "model",
   *  "solve"); a command that runs only that part offers only its rows. */
  std::string group;
  /** Kind::Choice: the names; the value is the index. */
  std::vector<std::string> choices;
  /** Number and Integer: the allowed range, each end open or closed. */
  double lowest = -std::numeric_limits<double>::infinity();
  double highest = std::numeric_limits<double>::infinity();
  bool   lowestOpen = false;
  bool   highestOpen = false;

  /** "(0, 1]", ">= 1", "> 0", ... or "" when any value is allowed. */
  std::string Range() const;
  /** Empty when `value` is allowed (a finite number in the range, an
   *  integer for Integer, 0/1 for Flag, an index for Choice); otherwise what
   *  is wrong, e.g. "must be (0, 1], got 1.5". */
  std::string Check(double value) const;
  /** The value that `text` gives ("0.01", "20", "true", a choice's name);
   *  throws bmr::Error naming the setting and what is allowed. Not for Text. */
  double Parse(const std::string & text) const;
  /** The command line's name of the setting: --name-with-dashes. */
  std::string OptionName() const;
};

/** Shortest text that reads back as `value` (integers without a decimal point). */
std::string
SettingNumberText(double value);

/** A row of the table of TSettings. */
template <typename TSettings>
struct SettingField : SettingFieldBase
{
  /** Number, Integer, Flag (0/1), Choice (index). */
  std::function<double(const TSettings &)> get;
  std::function<void(TSettings &, double)> set;
  /** Text. */
  std::function<std::string(const TSettings &)> getText;
  std::function<void(TSettings &, const std::string &)> setText;

  /** The value in `settings` as a scene file or command line writes it: 0.001, 20, true, anp, a path. */
  std::string
  Text(const TSettings & settings) const
  {
    switch (kind)
    {
      case Kind::Text:
        return getText(settings);
      case Kind::Flag:
        return get(settings) != 0.0 ? "true" : "false";
      case Kind::Choice:
        return choices.at(static_cast<std::size_t>(get(settings)));
      default:
        return SettingNumberText(get(settings));
    }
  }

  /** Sets the value from text (Parse and Check). */
  void
  SetText(TSettings & settings, const std::string & text) const
  {
    if (kind == Kind::Text)
    {
      setText(settings, text);
      return;
    }
    set(settings, Parse(text));
  }
};

/** A row with a numeric value (Number, Integer, Flag, Choice: see SettingField::get). */
template <typename TSettings>
SettingField<TSettings>
MakeSettingField(SettingFieldBase::Kind kind, std::string group, std::string name, std::string unit, double lowest,
                 bool lowestOpen, double highest, bool highestOpen, std::string meaning,
                 std::function<double(const TSettings &)> get, std::function<void(TSettings &, double)> set)
{
  SettingField<TSettings> field;
  field.kind = kind;
  field.group = std::move(group);
  field.name = std::move(name);
  field.unit = std::move(unit);
  field.meaning = std::move(meaning);
  field.lowest = lowest;
  field.lowestOpen = lowestOpen;
  field.highest = highest;
  field.highestOpen = highestOpen;
  field.get = std::move(get);
  field.set = std::move(set);
  return field;
}

/** The row of `name` in `fields`, or nullptr. */
template <typename TSettings>
const SettingField<TSettings> *
FindSettingField(const std::vector<SettingField<TSettings>> & fields, const std::string & name)
{
  for (const auto & field : fields)
  {
    if (field.name == name)
    {
      return &field;
    }
  }
  return nullptr;
}

/** The names of `fields`, comma-separated, for "unknown setting" messages. */
template <typename TSettings>
std::string
SettingNames(const std::vector<SettingField<TSettings>> & fields)
{
  std::string names;
  for (const auto & field : fields)
  {
    names += (names.empty() ? "" : ", ") + field.name;
  }
  return names;
}

/** A Markdown table of `fields` with the defaults of `defaults`: key, default, unit, allowed, meaning. */
template <typename TSettings>
std::string
SettingsMarkdown(const std::vector<SettingField<TSettings>> & fields, const TSettings & defaults)
{
  std::string text = "| key | default | unit | allowed | meaning |\n| --- | --- | --- | --- | --- |\n";
  for (const auto & field : fields)
  {
    const std::string value = field.Text(defaults);
    const bool        quoted = field.kind == SettingFieldBase::Kind::Choice || field.kind == SettingFieldBase::Kind::Text;
    text += "| `" + field.name + "` | " + (quoted ? "`\"" + value + "\"`" : value) + " | " + field.unit + " | " +
            field.Range() + " | " + field.meaning + " |\n";
  }
  return text;
}

} // namespace bmr

#endif

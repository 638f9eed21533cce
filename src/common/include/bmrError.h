// The one error type of the module, apart from the model so that headers
// needing only it (atomic writes, settings tables) do not pull the model in.
#ifndef bmrError_h
#define bmrError_h

#include <stdexcept>

namespace bmr
{

/** Every error of the core: the message names the object and what to do. */
class Error : public std::runtime_error
{
public:
  using std::runtime_error::runtime_error;
};

} // namespace bmr

#endif

// The same reader compiled as C++: the header must work from both languages.
#include "shm_reader_check.c"

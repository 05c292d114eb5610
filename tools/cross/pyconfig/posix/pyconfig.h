/* pyconfig.h for cross-compiling Tear Cloth's native modules for macOS (arm64 and x86-64) and
 * Linux arm64 (all LP64, little-endian, 32-bit wchar_t, 64-bit time_t, 32-bit pid_t, so one file
 * serves them; `zig cc -target aarch64-macos` / `x86_64-macos` / `aarch64-linux-gnu`) against the
 * CPython LIMITED API only (Py_LIMITED_API = 0x030B0000).
 *
 * Owned by tools/cross/native.py, which puts this folder in front of a copy of the build
 * Python's headers (without their own pyconfig.h: that one describes the Linux build machine).
 * Only what the limited-API headers read is defined here, with the values of python.org's and
 * Homebrew's macOS builds; nothing here may change the size or layout of a type that crosses the
 * ABI. On macOS and Linux an extension module is not linked to libpython: its Python symbols are
 * left undefined and bound by the loader to the running interpreter (macOS: `-undefined
 * dynamic_lookup`), so no import or export decoration is wanted (no Py_ENABLE_SHARED /
 * HAVE_DECLSPEC_DLL). */
#ifndef TEARCLOTH_CROSS_PYCONFIG_H
#define TEARCLOTH_CROSS_PYCONFIG_H

/* Py_ssize_t is ssize_t from <sys/types.h> on POSIX systems (pyport.h). */
#define HAVE_SSIZE_T 1

/* LP64 sizes: pointers, size_t and long are 64 bits. */
#define SIZEOF_VOID_P 8
#define SIZEOF_SIZE_T 8
#define SIZEOF_UINTPTR_T 8
#define SIZEOF_SHORT 2
#define SIZEOF_INT 4
#define SIZEOF_LONG 8
#define SIZEOF_LONG_LONG 8
#define SIZEOF_FLOAT 4
#define SIZEOF_DOUBLE 8
#define SIZEOF__BOOL 1

/* wchar_t is UTF-32 on macOS and glibc (unicodeobject.h requires the size). */
#define SIZEOF_WCHAR_T 4
#define HAVE_WCHAR_H 1

/* time_t is 64-bit and pid_t 32-bit on Darwin and 64-bit Linux (longobject.h's PyLong_FromPid). */
#define SIZEOF_TIME_T 8
#define SIZEOF_PID_T 4

/* IEEE-754 doubles, little-endian on both architectures; not WORDS_BIGENDIAN. */
#define DOUBLE_IS_LITTLE_ENDIAN_IEEE754 1

/* <stddef.h> for size_t, <unistd.h> is included by Python.h on every non-Windows system. */
#define HAVE_STDDEF_H 1
#define HAVE_UNISTD_H 1

/* Documentation strings are compiled in, as in every release build. */
#define WITH_DOC_STRINGS 1

#endif

/* pyconfig.h for cross-compiling Tear Cloth's native modules for 64-bit Windows (x86-64, MinGW-w64
 * C library with the Universal CRT, as `zig cc -target x86_64-windows-gnu` provides) against the
 * CPython LIMITED API only (Py_LIMITED_API = 0x030B0000, linked to python3.dll).
 *
 * Owned by tools/cross/native.py, which puts this folder in front of a copy of the build
 * Python's headers (without their own pyconfig.h: that one describes the Linux build machine).
 * Only what the limited-API headers read is defined here; CPython's PC/pyconfig.h (MSVC) sets the
 * same values on a real Windows build. Nothing here may change the size or layout of a type that
 * crosses the ABI: every value is the one of the Windows x64 ABI (LLP64). */
#ifndef TEARCLOTH_CROSS_PYCONFIG_H
#define TEARCLOTH_CROSS_PYCONFIG_H

/* Python.h leaves out <unistd.h> and takes the Windows branches of pyerrors.h/unicodeobject.h
 * (PyErr_SetFromWindowsErr, PyUnicode_DecodeMBCS declarations) on MS_WINDOWS. MS_WIN32 is also
 * set on 64-bit Windows by CPython's own pyconfig.h; MS_WIN64 marks the 64-bit pointer size. */
#define MS_WINDOWS 1
#define MS_WIN32 1
#define MS_WIN64 1
#define NT_THREADS 1

/* An extension module on Windows imports every API function and data object from the Python DLL
 * (__declspec(dllimport), through an import library) and exports its PyInit_* function
 * (__declspec(dllexport)): pyport.h picks those only when both of these are defined. */
#define Py_ENABLE_SHARED 1
#define HAVE_DECLSPEC_DLL 1

/* Py_ssize_t: 64-bit on Win64 (pyport.h otherwise derives it from these sizes, the same way). */
#define SIZEOF_VOID_P 8
#define SIZEOF_SIZE_T 8
#define SIZEOF_UINTPTR_T 8

/* LLP64: long is 32 bits on Windows, long long 64 (PyLong_AsLong and friends follow). */
#define SIZEOF_SHORT 2
#define SIZEOF_INT 4
#define SIZEOF_LONG 4
#define SIZEOF_LONG_LONG 8
#define SIZEOF_FLOAT 4
#define SIZEOF_DOUBLE 8
#define SIZEOF__BOOL 1

/* wchar_t is UTF-16 on Windows (unicodeobject.h requires the size). */
#define SIZEOF_WCHAR_T 2
#define HAVE_WCHAR_H 1

/* The Universal CRT's time_t is 64-bit; its pid is an int (longobject.h's PyLong_FromPid). */
#define SIZEOF_TIME_T 8
#define SIZEOF_PID_T 4

/* IEEE-754 doubles, little-endian (pymath.h / floatobject.h); not WORDS_BIGENDIAN. */
#define DOUBLE_IS_LITTLE_ENDIAN_IEEE754 1

/* <stddef.h> for size_t (Python.h includes it only when told). */
#define HAVE_STDDEF_H 1

/* Documentation strings are compiled in, as in every release build. */
#define WITH_DOC_STRINGS 1

#endif

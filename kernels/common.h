/* Shared definitions of the clnlos kernels.
 * Build options: -DREAL_T=float|double (default float), -DUSE_FP64 when REAL_T is double. */
#ifndef CLNLOS_COMMON_H
#define CLNLOS_COMMON_H

#ifdef USE_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif

#ifndef REAL_T
#define REAL_T float
#endif
typedef REAL_T real_t;

#define PI_R ((real_t)3.14159265358979323846)

#endif

/* Complex numbers of the kernels' real type (pyopencl-complex.h), shared by wiener.cl and
 * fk.cl: cplx_t and the operations they use. Include after common.h. */
#ifndef CLNLOS_COMPLEX_H
#define CLNLOS_COMPLEX_H

#ifdef USE_FP64
#define PYOPENCL_DEFINE_CDOUBLE
#endif
#include <pyopencl-complex.h>

#ifdef USE_FP64
typedef cdouble_t cplx_t;
#define CNEW cdouble_new
#define CADD cdouble_add
#define CMUL cdouble_mul
#define CRMUL cdouble_mulr
#define CCONJ cdouble_conj
#else
typedef cfloat_t cplx_t;
#define CNEW cfloat_new
#define CADD cfloat_add
#define CMUL cfloat_mul
#define CRMUL cfloat_mulr
#define CCONJ cfloat_conj
#endif
#define CABS2(z) ((z).real * (z).real + (z).imag * (z).imag)

#endif

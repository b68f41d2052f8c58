/* Zeroing by a kernel, for Oclgrind only: there memory set by clEnqueueFillBuffer reads as
 * uninitialised, and memory set by clEnqueueWriteBuffer reads as uninitialised again after
 * a read-write map of the buffer, so runtime.fill_zero writes its zeros with this kernel.
 * Every other device uses clEnqueueFillBuffer (a memset). */
__kernel void zero_bytes(__global uchar *restrict a, const ulong offset, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n)
        a[offset + i] = 0;
}

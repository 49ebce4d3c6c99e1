/*
 * LD_PRELOAD shim for linux.uml (scripts/uml-vcan): lets User-Mode Linux 6.1 (Debian
 * bookworm's) run on hosts whose XSAVE area is larger than the one it knows.
 *
 * UML saves and restores a guest thread's FPU state with
 * ptrace(PTRACE_{GET,SET}REGSET, NT_X86_XSTATE) on a buffer of the legacy + AVX size
 * (832 bytes). The host kernel truncates a GETREGSET to the buffer, but refuses a
 * SETREGSET that is not exactly its full XSAVE size with EFAULT; on a host with
 * AVX-512, PKRU or AMX state the guest's init then dies at its first context switch
 * ("userspace - ptrace set fp regs failed, errno = 14", kernel panic).
 *
 * This shim does both requests on a full-size buffer: a get copies the part UML asked
 * for; a set reads the thread's full state, overwrites the part UML gives and writes
 * the whole. State beyond UML's part (AVX-512 registers, AMX tiles) keeps the host
 * thread's current contents; uml-vcan therefore keeps glibc in the guest off its
 * AVX-512 code (GLIBC_TUNABLES).
 *
 * Build: cc -O2 -shared -fPIC -o uml-xstate.so uml-xstate.c -ldl
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <stdarg.h>
#include <string.h>
#include <sys/ptrace.h>
#include <sys/types.h>
#include <sys/uio.h>

typedef long (*ptrace_fn)(int, pid_t, void *, void *);

/* Larger than any x86 XSAVE area (about 11 KiB with AMX). UML calls ptrace from one
 * thread, so one buffer does. */
static unsigned char full_state[65536];

long ptrace(enum __ptrace_request request, ...)
{
    va_list args;
    va_start(args, request);
    pid_t pid = va_arg(args, pid_t);
    void *addr = va_arg(args, void *);
    void *data = va_arg(args, void *);
    va_end(args);

    static ptrace_fn real_ptrace;
    if (!real_ptrace)
        real_ptrace = (ptrace_fn)dlsym(RTLD_NEXT, "ptrace");

    if ((request != PTRACE_GETREGSET && request != PTRACE_SETREGSET) ||
        (long)addr != NT_X86_XSTATE)
        return real_ptrace(request, pid, addr, data);

    struct iovec *asked = data;
    struct iovec full = { full_state, sizeof full_state };
    long result = real_ptrace(PTRACE_GETREGSET, pid, addr, &full);
    if (result < 0)
        return result;
    size_t part = asked->iov_len < full.iov_len ? asked->iov_len : full.iov_len;
    if (request == PTRACE_GETREGSET) {
        memcpy(asked->iov_base, full_state, part);
        asked->iov_len = part;
        return 0;
    }
    memcpy(full_state, asked->iov_base, part);
    return real_ptrace(PTRACE_SETREGSET, pid, addr, &full);
}

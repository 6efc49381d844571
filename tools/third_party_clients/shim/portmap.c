/* LD_PRELOAD helper written for barrett-twin: Barrett's BHand API opens fixed device names
 * ("/dev/ttyS0".., "/dev/ttyUSB0"..); this maps the one named in $PORTMAP_FROM onto $PORTMAP_TO
 * (the emulator's pty) so that the API runs unchanged. Every other path is opened as asked. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>

static const char *mapped(const char *path) {
    const char *from = getenv("PORTMAP_FROM");
    const char *to = getenv("PORTMAP_TO");
    return (from && to && path && strcmp(path, from) == 0) ? to : path;
}

static int forward(const char *name, const char *path, int flags, va_list ap) {
    int (*real)(const char *, int, ...) = (int (*)(const char *, int, ...))dlsym(RTLD_NEXT, name);
    if (flags & (O_CREAT | O_TMPFILE)) {
        mode_t mode = (mode_t)va_arg(ap, int);
        return real(mapped(path), flags, mode);
    }
    return real(mapped(path), flags);
}

int open(const char *path, int flags, ...) {
    va_list ap;
    va_start(ap, flags);
    int fd = forward("open", path, flags, ap);
    va_end(ap);
    return fd;
}

int open64(const char *path, int flags, ...) {
    va_list ap;
    va_start(ap, flags);
    int fd = forward("open64", path, flags, ap);
    va_end(ap);
    return fd;
}

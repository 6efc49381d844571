// A small program written for barrett-twin: drives Barrett's BHand API 4.4.3 (unchanged, built from
// its public sources) through start-up, supervisory calls and a RealTime loop, and prints every call
// with its return value. Usage: bhand_client BAUD CYCLES  (the port is /dev/ttyUSB9, mapped onto the
// emulator's pty by portmap.so).
#include "BHand.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <thread>

static int failures = 0;

static double now_ms();

static int report(const char *call, int result, double t0) {
    double ms = now_ms() - t0;
    std::printf("%-44s -> %d  (%.0f ms)\n", call, result, ms);
    std::fflush(stdout);
    if (result != 0) failures++;
    return result;
}

static double now_ms() {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

#define CALL(expr) ([&] { double start_ms = now_ms(); int result = (expr); return report(#expr, result, start_ms); }())

int main(int argc, char **argv) {
    int baud = argc > 1 ? std::atoi(argv[1]) : 9600;
    int cycles = argc > 2 ? std::atoi(argv[2]) : 1000;
    BHand bh;
    // The API's worker thread (started by the BHand constructor) sets its "request complete" event at
    // the top of its loop; a request made before that thread first runs returns at once, and Reset
    // then reads a result that does not exist yet (a SIGSEGV in BHandDriver::Reset, ~1 run in 4 on a
    // busy 2-core machine). Give the thread time to start: a client-side wait, their code unchanged.
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    char reply[4096] = "";
    int values[16];
    int temperature = 0;

    if (CALL(bh.InitSoftware(-9, THREAD_PRIORITY_TIME_CRITICAL))) return 1;
    if (baud != 9600 && CALL(bh.Baud(baud))) return 1;
    if (CALL(bh.InitHand(""))) return 1;

    // Supervisory calls
    CALL(bh.Command("VERS", reply));
    std::printf("    VERS: %s\n", reply);
    CALL(bh.Get("1234", "P", values));
    std::printf("    P: %d %d %d %d\n", values[0], values[1], values[2], values[3]);
    CALL(bh.Set("123", "MCV", 80));
    CALL(bh.Get("1", "MCV", values));
    std::printf("    1 MCV: %d\n", values[0]);
    CALL(bh.PGet("TEMP", &temperature));
    std::printf("    TEMP: %d\n", temperature);
    CALL(bh.GoToPosition("123", 4000));
    CALL(bh.Get("123", "P", values));
    std::printf("    P after 123M 4000: %d %d %d\n", values[0], values[1], values[2]);
    CALL(bh.Close("G"));
    CALL(bh.Open("G"));
    CALL(bh.StepClose("S", 500));
    CALL(bh.GoToHome("1234"));

    // RealTime: velocity control with gains, feedback of velocity, strain, position and temperature
    CALL(bh.RTSetFlags("1234", true, 1, true, false, true, 1, true, true, false, 1, false, false, false, true));
    if (CALL(bh.RTStart("1234"))) return 1;
    int rt_failures = 0;
    double start = now_ms();
    for (int i = 0; i < cycles; i++) {
        int v = (i / 100) % 2 ? -20 : 20;
        for (char m = '1'; m <= '3'; m++) {
            bh.RTSetVelocity(m, v);
            bh.RTSetGain(m, 50);
        }
        bh.RTSetVelocity('4', 0);
        bh.RTSetGain('4', 50);
        int r = bh.RTUpdate(true, true);
        if (r != 0) {
            rt_failures++;
            std::printf("RTUpdate cycle %d -> %d\n", i, r);
            break;
        }
    }
    double elapsed_s = (now_ms() - start) / 1000.0;
    std::printf("%-44s -> %s  (%d cycles in %.2f s: %.1f cycles/s)\n", "RTUpdate x N", rt_failures ? "FAILED" : "0",
                cycles, elapsed_s, cycles / elapsed_s);
    std::printf("    last feedback: P %d %d %d %d, strain %d %d %d, temperature %d\n", bh.RTGetPosition('1'),
                bh.RTGetPosition('2'), bh.RTGetPosition('3'), bh.RTGetPosition('4'), bh.RTGetStrain('1'),
                bh.RTGetStrain('2'), bh.RTGetStrain('3'), bh.RTGetTemp());
    failures += rt_failures;
    CALL(bh.RTAbort());
    CALL(bh.StopMotor("1234"));
    if (baud != 9600) CALL(bh.Baud(9600));
    std::printf("RESULT bhand baud=%d cycles=%d rate=%.1f failures=%d\n", baud, cycles, cycles / elapsed_s, failures);
    return failures ? 1 : 0;
}

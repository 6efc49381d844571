// A small program written for barrett-twin: drives dmiller12/libgripper's BarrettHand (unchanged,
// built from its public sources) through initialize(), then its velocity mode and its position mode,
// each for about CYCLES RealTime cycles, and prints what happens. Usage:
//   libgripper_client PORT CYCLES SECONDS_PER_CYCLE
// The library keeps its cycle count to itself: the emulator reports the blocks of each LOOP session.
#include "gripper/barrett/barrett_hand.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

using gripper::barrett::BarrettHand;
using gripper::barrett::MotorGroup;

static void show(const char *what, const BarrettHand &hand) {
    auto s = hand.getLatestState();
    std::printf("    %s: joints %.3f %.3f %.3f %.3f rad\n", what, s.joint_positions[0], s.joint_positions[1],
                s.joint_positions[2], s.joint_positions[3]);
    std::fflush(stdout);
}

int main(int argc, char **argv) {
    if (argc < 4) {
        std::fprintf(stderr, "usage: %s PORT CYCLES SECONDS_PER_CYCLE\n", argv[0]);
        return 2;
    }
    const char *port = argv[1];
    int cycles = std::atoi(argv[2]);
    double period_s = std::atof(argv[3]);
    auto run_for = std::chrono::duration<double>(cycles * period_s);

    BarrettHand hand;
    auto t0 = std::chrono::steady_clock::now();
    bool ok = hand.initialize(port);
    double init_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("BarrettHand::initialize(\"%s\") -> %s  (%.2f s)\n", port, ok ? "true" : "false", init_s);
    std::fflush(stdout);
    if (!ok) return 1;

    std::printf("velocity mode: setVelocity(0.4 rad/s fingers, 0 spread) for %.1f s\n", run_for.count());
    std::fflush(stdout);
    hand.setVelocity(0.4, 0.0);
    std::this_thread::sleep_for(run_for / 2);
    show("half way", hand);
    hand.setVelocity(-0.4, 0.0);
    std::this_thread::sleep_for(run_for / 2);
    show("end", hand);

    std::printf("open(AllFingers): leaves RealTime, GO, LOOP again\n");
    std::fflush(stdout);
    hand.open(MotorGroup::AllFingers);

    std::printf("position mode: setPosition(1.0 1.0 1.0 rad, spread 0.5 rad) for %.1f s\n", run_for.count());
    std::fflush(stdout);
    hand.setPosition({1.0, 1.0, 1.0, 0.5});
    std::this_thread::sleep_for(run_for);
    show("end", hand);

    hand.shutdown();
    std::printf("RESULT libgripper initialize=%s\n", ok ? "true" : "false");
    return 0;
}

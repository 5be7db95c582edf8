// A C++17 host of the taut plugin shaped like a ros2_control hardware component
// (hardware_interface::SystemInterface): on_init / on_configure / on_activate, then read() and
// write() every cycle from the controller manager's loop, on_deactivate / on_cleanup at the end.
// The ros2_control types are replaced by a tiny stand-in below (no ROS needed to build or run
// it); docs/plugin.md says what changes in a real pluginlib export.
//
// The "hardware" is taut's simulated robot (taut_sim_*): in a real component read() would take
// the drives' position actual values, the load cells and the tracker from their buses, and
// write() would send the controlword intent and the CSP/CST targets. The simulated robot is in
// libtaut built with `cargo build -p taut-ffi --features sim` (see ffi/tests/hosts.rs).
//
//   cpp-host CONFIG.toml DATA_DIR [SEED [SPEED]]   (exit status 0: hot-swapped, anchors near the truth)
#include "taut.h"

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <thread>

// ---- stand-in for the ros2_control / rclcpp types the component uses ----------------------
namespace rclcpp {
struct Time {
    double s = 0.0;
    double seconds() const { return s; }
};
struct Duration {
    double s = 0.0;
    double seconds() const { return s; }
};
}  // namespace rclcpp

namespace hardware_interface {
enum class return_type { OK, ERROR };
struct HardwareInfo {
    std::string name;
    std::map<std::string, std::string> hardware_parameters;  // the URDF <param> tags
};
namespace lifecycle {
enum class CallbackReturn { SUCCESS, FAILURE, ERROR };
}
using CallbackReturn = lifecycle::CallbackReturn;

class SystemInterface {
public:
    virtual ~SystemInterface() = default;
    virtual CallbackReturn on_init(const HardwareInfo &info) {
        info_ = info;
        return CallbackReturn::SUCCESS;
    }
    virtual CallbackReturn on_configure() = 0;
    virtual CallbackReturn on_activate() = 0;
    virtual CallbackReturn on_deactivate() = 0;
    virtual CallbackReturn on_cleanup() = 0;
    virtual return_type read(const rclcpp::Time &time, const rclcpp::Duration &period) = 0;
    virtual return_type write(const rclcpp::Time &time, const rclcpp::Duration &period) = 0;

protected:
    HardwareInfo info_;
};
}  // namespace hardware_interface

// ---- the component -------------------------------------------------------------------------
namespace taut_ros2 {

using hardware_interface::CallbackReturn;
using hardware_interface::return_type;

// Calls the C ABI; a failure is logged with taut_last_error and mapped to ERROR.
static bool ok(TautError e, const char *what) {
    if (e == TAUT_ERROR_OK) return true;
    char msg[1024];
    taut_last_error(msg, sizeof msg);
    std::fprintf(stderr, "TautSystem: %s failed (error %d): %s\n", what, static_cast<int>(e), msg);
    return false;
}

class TautSystem final : public hardware_interface::SystemInterface {
public:
    ~TautSystem() override {
        taut_cleanup(plugin_);
        taut_sim_free(sim_);
    }

    CallbackReturn on_init(const hardware_interface::HardwareInfo &info) override {
        SystemInterface::on_init(info);
        const auto &p = info.hardware_parameters;
        if (p.count("config") == 0 || p.count("data_dir") == 0) {
            std::fprintf(stderr, "TautSystem: the hardware parameters need `config` and `data_dir`\n");
            return CallbackReturn::ERROR;
        }
        config_ = p.at("config");
        data_dir_ = p.at("data_dir");
        seed_ = p.count("sim_seed") ? std::strtoull(p.at("sim_seed").c_str(), nullptr, 10) : 1;
        return CallbackReturn::SUCCESS;
    }

    // Parse and validate, allocate, start the calibrator thread; no bus traffic.
    CallbackReturn on_configure() override {
        if (!ok(taut_sim_new(config_.c_str(), seed_, &sim_), "taut_sim_new")) return CallbackReturn::ERROR;
        TautOptions o;
        taut_options_init(&o);
        o.devices = TAUT_DEVICES_HOST;
        o.data_dir = data_dir_.c_str();
        return ok(taut_configure(config_.c_str(), TAUT_CONFIG_PATH, &o, &plugin_), "taut_configure") ? CallbackReturn::SUCCESS
                                                                                                       : CallbackReturn::ERROR;
    }

    CallbackReturn on_activate() override {
        return ok(taut_activate(plugin_), "taut_activate") ? CallbackReturn::SUCCESS : CallbackReturn::ERROR;
    }

    CallbackReturn on_deactivate() override {
        return ok(taut_deactivate(plugin_), "taut_deactivate") ? CallbackReturn::SUCCESS : CallbackReturn::ERROR;
    }

    CallbackReturn on_cleanup() override {
        bool r = ok(taut_cleanup(plugin_), "taut_cleanup");
        plugin_ = nullptr;
        return r ? CallbackReturn::SUCCESS : CallbackReturn::ERROR;
    }

    // The state interfaces: the devices' readings (here from the simulated robot).
    return_type read(const rclcpp::Time &time, const rclcpp::Duration &) override {
        return ok(taut_sim_read(sim_, time.seconds(), &inputs_), "taut_sim_read") ? return_type::OK : return_type::ERROR;
    }

    // taut computes the commands from this cycle's readings, then they go to the drives.
    return_type write(const rclcpp::Time &time, const rclcpp::Duration &period) override {
        if (!ok(taut_update(plugin_, time.seconds(), period.seconds(), &inputs_, &commands_), "taut_update")) return return_type::ERROR;
        return ok(taut_sim_write(sim_, time.seconds(), period.seconds(), &commands_), "taut_sim_write") ? return_type::OK
                                                                                                          : return_type::ERROR;
    }

    // Operator side (a non-real-time thread in ros2_control: a service or a diagnostics timer).
    const TautPlugin *plugin() const { return plugin_; }
    const TautSim *sim() const { return sim_; }

private:
    std::string config_, data_dir_;
    uint64_t seed_ = 1;
    TautSim *sim_ = nullptr;
    TautPlugin *plugin_ = nullptr;
    TautInputs inputs_{};
    TautCommands commands_{};
};

}  // namespace taut_ros2

// ---- a controller manager in miniature -----------------------------------------------------
int main(int argc, char **argv) {
    if (argc < 3) {
        std::fprintf(stderr, "usage: %s CONFIG.toml DATA_DIR [SEED [SPEED]]\n", argv[0]);
        return 2;
    }
    hardware_interface::HardwareInfo info;
    info.name = "taut";
    info.hardware_parameters["config"] = argv[1];
    info.hardware_parameters["data_dir"] = argv[2];
    if (argc > 3) info.hardware_parameters["sim_seed"] = argv[3];
    const double speed = argc > 4 ? std::atof(argv[4]) : 1.0;

    using hardware_interface::CallbackReturn;
    using hardware_interface::return_type;
    taut_ros2::TautSystem sys;
    if (sys.on_init(info) != CallbackReturn::SUCCESS || sys.on_configure() != CallbackReturn::SUCCESS ||
        sys.on_activate() != CallbackReturn::SUCCESS)
        return 1;
    TautSimTruth truth;
    taut_sim_truth(sys.sim(), &truth);

    const rclcpp::Duration period{0.002};
    const auto wall0 = std::chrono::steady_clock::now();
    uint64_t initial = 0, calibrated = 0;
    bool done = false;
    rclcpp::Time now{0.0};
    // 3600 simulated s: 900 s of wall at speed 4 (the calibrator runs in wall-clock time and
    // slows on a loaded machine); a timeout, not a requirement.
    for (uint64_t k = 0; now.s < 3600.0 && !done; k++) {
        if (sys.read(now, period) != return_type::OK || sys.write(now, period) != return_type::OK) return 1;
        now.s += period.s;
        if (speed > 0.0) std::this_thread::sleep_until(wall0 + std::chrono::duration<double>(now.s / speed));
        if (k % 50 != 0) continue;
        TautEvent ev;
        while (taut_poll_event(sys.plugin(), &ev) == TAUT_ERROR_OK) {
            if (ev.kind == TAUT_EVENT_KIND_FAULT) {
                char json[4096];
                taut_status_json(sys.plugin(), json, sizeof json, nullptr);
                std::fprintf(stderr, "cpp-host: safety reaction at t=%.2f s: %s\n", ev.t_s, json);
                return 1;
            }
            if (ev.kind == TAUT_EVENT_KIND_CALIBRATION) {
                std::printf("cpp-host: t=%7.2f s  %s %s (version %llu)\n", ev.t_s, ev.initial ? "initial estimate" : "calibration",
                            ev.accepted ? "accepted" : "REFUSED", static_cast<unsigned long long>(ev.value));
                if (!ev.accepted) return 1;
                (ev.initial ? initial : calibrated) = ev.value;
            }
        }
        TautStatus st;
        if (taut_status(sys.plugin(), &st) != TAUT_ERROR_OK) return 1;
        done = calibrated != 0 && st.params_version == calibrated && !st.swap_active;
    }
    if (!done) {
        std::fprintf(stderr, "cpp-host: no hot-swap within 3600 s of simulated time\n");
        return 1;
    }
    TautParams par;
    if (taut_params(sys.plugin(), &par) != TAUT_ERROR_OK) return 1;
    bool bad = initial == 0 || par.version <= initial;
    for (uint32_t j = 0; j < par.n_cables; j++) {
        for (int i = 0; i < 3; i++) {
            const double err = std::fabs(par.anchors_m[j][i] - truth.anchors_m[j][i]);
            // 4.46 sigma: Bonferroni over the 12 coordinates for a chance failure of 1e-4 (c-host).
            if (!(err < 4.46 * par.anchor_sigma_m[j][i] + 2e-4)) {
                std::fprintf(stderr, "cpp-host: anchor %u[%d] off by %.2f mm, sigma %.2f mm\n", j, i, err * 1e3,
                             par.anchor_sigma_m[j][i] * 1e3);
                bad = true;
            }
        }
    }
    std::printf("cpp-host: hot-swapped from version %llu to %llu at t=%.2f s\n", static_cast<unsigned long long>(initial),
                static_cast<unsigned long long>(par.version), now.s);
    if (sys.on_deactivate() != CallbackReturn::SUCCESS || sys.on_cleanup() != CallbackReturn::SUCCESS) return 1;
    if (bad) return 1;
    std::printf("cpp-host: ok\n");
    return 0;
}

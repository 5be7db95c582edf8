# Print an optspec for argparse to handle cmd's options that are independent of any subcommand.
function __fish_taut_global_optspecs
    string join \n v/verbose q/quiet h/help V/version
end

function __fish_taut_needs_command
    # Figure out if the current invocation already has a command.
    set -l cmd (commandline -opc)
    set -e cmd[1]
    argparse -s (__fish_taut_global_optspecs) -- $cmd 2>/dev/null
    or return
    if set -q argv[1]
        # Also print the command, so this can be used to figure out what it is.
        echo $argv[1]
        return 1
    end
    return 0
end

function __fish_taut_using_subcommand
    set -l cmd (__fish_taut_needs_command)
    test -z "$cmd"
    and return 1
    contains -- $cmd[1] $argv
end

complete -c taut -n "__fish_taut_needs_command" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_needs_command" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_needs_command" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_needs_command" -s V -l version -d 'Print version'
complete -c taut -n "__fish_taut_needs_command" -f -a "demo" -d 'Simulate a robot, record its initialisation and excitation, calibrate it, print the results'
complete -c taut -n "__fish_taut_needs_command" -f -a "simulate" -d 'Write a recording (cdpr-recording v1) of a simulated robot'
complete -c taut -n "__fish_taut_needs_command" -f -a "calibrate" -d 'Calibrate anchors and encoder offsets from any recording (CSV or MCAP), real or simulated'
complete -c taut -n "__fish_taut_needs_command" -f -a "start" -d 'Run the robot\'s controller: start-up calibration, hot-swap, operation (--sim: simulated robot)'
complete -c taut -n "__fish_taut_needs_command" -f -a "ctl" -d 'Talk to a running `taut start`: status, watch, move, recalibrate, stop, estop, reset, params, outcome'
complete -c taut -n "__fish_taut_needs_command" -f -a "diagnose" -d 'Find the physics the ideal model leaves out: name it, model it, show the fit improve'
complete -c taut -n "__fish_taut_needs_command" -f -a "probe" -d 'Find every CAN drive, configure its PDOs, print nodes, states, positions and the bus load'
complete -c taut -n "__fish_taut_needs_command" -f -a "export" -d 'Convert a recording (cdpr-recording v1) to MCAP for Foxglove, PlotJuggler and rosbag2'
complete -c taut -n "__fish_taut_needs_command" -f -a "completions" -d 'Print a shell completion script: taut completions bash > /etc/bash_completion.d/taut'
complete -c taut -n "__fish_taut_needs_command" -f -a "man" -d 'Print the manual page (roff): taut man > taut.1; man ./taut.1. With --dir: write taut.1 and one page per subcommand (taut-ctl.1, ...) there'
complete -c taut -n "__fish_taut_needs_command" -f -a "help" -d 'Print this message or the help of the given subcommand(s)'
complete -c taut -n "__fish_taut_using_subcommand demo" -l config -d 'Robot configuration whose nominal anchors the simulated site deviates from. Default: the built-in ARAS-CAM-like robot' -r -F
complete -c taut -n "__fish_taut_using_subcommand demo" -s o -l output -d 'Output recording (cdpr-recording v1 CSV); by default recording.csv in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand demo" -l truth -d 'Write the simulation truth (anchors, offsets) as taut-params TOML here' -r -F
complete -c taut -n "__fish_taut_using_subcommand demo" -l seed -d 'Random seed; the same seed gives the same recording' -r
complete -c taut -n "__fish_taut_using_subcommand demo" -l duration -d 'Duration of the excitation run, s' -r
complete -c taut -n "__fish_taut_using_subcommand demo" -l rate -d 'Sample rate, Hz' -r
complete -c taut -n "__fish_taut_using_subcommand demo" -l loose-fraction -d 'Fraction of samples that should have a loose cable (excursions to the workspace edge)' -r
complete -c taut -n "__fish_taut_using_subcommand demo" -l effect -d 'Switch on cable physics that the ideal model leaves out, e.g. `elasticity=20000` (EA, N), `sag=0.5` (N/m), `pulley=0.05` (m), `scale=1.002`, `time-offset=0.02` (s), `backlash=0.002` (m), `spool-buildup=-5e-6` (m per turn; `drum-buildup` too), `loadcell-gain=1.03` (`load-cell-gain` too), `friction=0.2` (mu theta), `compliance=1.5e-6` (m/N). Repeatable' -r
complete -c taut -n "__fish_taut_using_subcommand demo" -l json -d 'Write the results as JSON to this file' -r -F
complete -c taut -n "__fish_taut_using_subcommand demo" -l plot -d 'Write figures (SVG and PNG) into this directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand demo" -l no-three-phase -d 'Leave out the guided three-phase initialisation motion'
complete -c taut -n "__fish_taut_using_subcommand demo" -l no-tensions -d 'Leave out the tensions (a robot without load cells)'
complete -c taut -n "__fish_taut_using_subcommand demo" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand demo" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand demo" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand simulate" -l config -d 'Robot configuration whose nominal anchors the simulated site deviates from. Default: the built-in ARAS-CAM-like robot' -r -F
complete -c taut -n "__fish_taut_using_subcommand simulate" -s o -l output -d 'Output recording (cdpr-recording v1 CSV); by default recording.csv in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand simulate" -l truth -d 'Write the simulation truth (anchors, offsets) as taut-params TOML here' -r -F
complete -c taut -n "__fish_taut_using_subcommand simulate" -l seed -d 'Random seed; the same seed gives the same recording' -r
complete -c taut -n "__fish_taut_using_subcommand simulate" -l duration -d 'Duration of the excitation run, s' -r
complete -c taut -n "__fish_taut_using_subcommand simulate" -l rate -d 'Sample rate, Hz' -r
complete -c taut -n "__fish_taut_using_subcommand simulate" -l loose-fraction -d 'Fraction of samples that should have a loose cable (excursions to the workspace edge)' -r
complete -c taut -n "__fish_taut_using_subcommand simulate" -l effect -d 'Switch on cable physics that the ideal model leaves out, e.g. `elasticity=20000` (EA, N), `sag=0.5` (N/m), `pulley=0.05` (m), `scale=1.002`, `time-offset=0.02` (s), `backlash=0.002` (m), `spool-buildup=-5e-6` (m per turn; `drum-buildup` too), `loadcell-gain=1.03` (`load-cell-gain` too), `friction=0.2` (mu theta), `compliance=1.5e-6` (m/N). Repeatable' -r
complete -c taut -n "__fish_taut_using_subcommand simulate" -l no-three-phase -d 'Leave out the guided three-phase initialisation motion'
complete -c taut -n "__fish_taut_using_subcommand simulate" -l no-tensions -d 'Leave out the tensions (a robot without load cells)'
complete -c taut -n "__fish_taut_using_subcommand simulate" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand simulate" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand simulate" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l config -d 'Robot configuration (platform points, noise model). Without it: point-mass platform' -r -F
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l json -d 'Write the results as JSON to this file' -r -F
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l plot -d 'Write figures (SVG and PNG) into this directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l out -d 'Write the calibrated parameters (taut-params v5 TOML: anchors, offsets, their 1-sigma) to this file, atomically' -r -F
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l report -d 'Write a self-contained HTML report (verdict, tables, figures) to this file, atomically' -r -F
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l compare -d 'Also calibrate without force weighting, to show what force weighting changes (tables, JSON `unweighted`, figures). Off by default: it doubles the solve'
complete -c taut -n "__fish_taut_using_subcommand calibrate" -l allow-swapped -d 'Calibrate cables whose anchors land at other cables\' nominal anchors (a swapped pair of length columns or drives) as recorded, instead of refusing: the nominal anchors they are checked against follow the swap'
complete -c taut -n "__fish_taut_using_subcommand calibrate" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand calibrate" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand calibrate" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand start" -l config -d 'Robot configuration (TOML). With --sim, defaults to the ARAS-CAM-like example robot' -r -F
complete -c taut -n "__fish_taut_using_subcommand start" -l json -d 'Write the summary as JSON to this file' -r -F
complete -c taut -n "__fish_taut_using_subcommand start" -l seed -d 'Seed of the simulated site (--sim)' -r
complete -c taut -n "__fish_taut_using_subcommand start" -l data-dir -d 'Override `daemon.data_dir` (recordings, parameter history)' -r -F
complete -c taut -n "__fish_taut_using_subcommand start" -l socket -d 'Override `daemon.socket`' -r -F
complete -c taut -n "__fish_taut_using_subcommand start" -l can -d 'With --sim: put the virtual drives and the CANopen master on this SocketCAN interface (e.g. `vcan0`) instead of an in-process virtual bus' -r
complete -c taut -n "__fish_taut_using_subcommand start" -l params -d 'A parameter file (taut-params v1 to v5, e.g. from `taut diagnose --out`): the length effects it carries are modelled and refitted by every calibration, starting from its values; its load-cell gains and friction correct the loop\'s tensions, carried unchanged' -r -F
complete -c taut -n "__fish_taut_using_subcommand start" -l sim-effect -d 'With --sim: conceal an effect in the simulated site, NAME=VALUE (as `taut simulate --effect`: elasticity=20000, scale=1.003, pulley=0.05, sag, time-offset, backlash, spool-buildup, compliance, loadcell-gain, friction; the last two change the cells\' readings only)' -r
complete -c taut -n "__fish_taut_using_subcommand start" -l sim -d 'Run against the simulated robot instead of hardware'
complete -c taut -n "__fish_taut_using_subcommand start" -l once -d 'Exit after the start-up calibration with a summary'
complete -c taut -n "__fish_taut_using_subcommand start" -l no-tracker -d 'With --sim: the simulated robot has no tracker; the start-up runs dwell poses and calibrates from the encoders and load cells (`motion.startup = "dwell"`)'
complete -c taut -n "__fish_taut_using_subcommand start" -l sim-time -d 'With --sim --once: run the start-up in simulated time, the whole robot stack in lockstep on one simulated clock, as fast as the CPU allows (the same seed gives the same run, bit for bit). The JSON gets a `sim_time` object with the speed-up over real time'
complete -c taut -n "__fish_taut_using_subcommand start" -l dynamic -d 'With --sim-time: the simulated plant has dynamics (the platform swings on elastic, damped 1 MN cables) instead of moving from one static equilibrium to the next; the initialisation phases reel at most 0.5 m'
complete -c taut -n "__fish_taut_using_subcommand start" -l sim-faults -d 'With --sim-time: faults drawn from the seed (lost and late CAN frames, tracker dropouts, a pause of the load cells)'
complete -c taut -n "__fish_taut_using_subcommand start" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand start" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand start" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "status" -d 'State, goal, calibration (parameter version, worst 1-sigma), drives, load cells, tracker, faults, loop health'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "watch" -d 'Follow what happens (states, phases, faults, parameter swaps, calibration outcomes, goals, resets, loop health), one line per event, until the daemon stops or Ctrl-C'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "move" -d 'Move the platform to X Y Z (m) in a straight line at `motion.move_speed_m_s`'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "recalibrate" -d 'Run the excitation again, recalibrate, hot-swap if better; the platform is brought back to where it was (status and log say where it stopped if it could not be)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "stop" -d 'Controlled stop: hold, disable the drives, end the daemon'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "estop" -d 'Emergency stop: quick stop, latched until `reset`'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "reset" -d 'Clear a latched safety reaction and re-enable the drives holding where they stand; waits for the outcome'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "params" -d 'The parameters in force: anchors, encoder offsets, their 1-sigma'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "outcome" -d 'One calibration outcome in full (estimate, sigmas, every data problem); `status` lists the newest with their numbers'
complete -c taut -n "__fish_taut_using_subcommand ctl; and not __fish_seen_subcommand_from status watch move recalibrate stop estop reset params outcome help" -f -a "help" -d 'Print this message or the help of the given subcommand(s)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from status" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -l from -d 'Start from this event number (default: the next one; 1: everything still kept)' -r
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from watch" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l tolerance -d 'Arrival tolerance for --wait, mm' -r
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l timeout -d 'Give up waiting after this many seconds' -r
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l wait -d 'Wait until the platform arrives (tracker within --tolerance of the goal), or the move is refused, interrupted or stopped by a fault; print the final error. Exit status 1 unless it arrived'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from move" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -l timeout -d 'Give up waiting after this many seconds' -r
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -l wait -d 'Wait for the calibration\'s outcome and the platform\'s return; exit status 1 if it did not get back'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from recalibrate" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from stop" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from estop" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from reset" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from params" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -l socket -d 'Control socket; default: `daemon.socket` of --config, else /run/taut/taut.sock (the robot\'s), else, when that does not exist, the simulated robot\'s taut-sim-data/taut.sock in the current directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -l config -d 'Robot configuration to take the socket path from (`daemon.socket`)' -r -F
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -l json -d 'Print the daemon\'s JSON replies instead of the summaries for people'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from outcome" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "status" -d 'State, goal, calibration (parameter version, worst 1-sigma), drives, load cells, tracker, faults, loop health'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "watch" -d 'Follow what happens (states, phases, faults, parameter swaps, calibration outcomes, goals, resets, loop health), one line per event, until the daemon stops or Ctrl-C'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "move" -d 'Move the platform to X Y Z (m) in a straight line at `motion.move_speed_m_s`'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "recalibrate" -d 'Run the excitation again, recalibrate, hot-swap if better; the platform is brought back to where it was (status and log say where it stopped if it could not be)'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "stop" -d 'Controlled stop: hold, disable the drives, end the daemon'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "estop" -d 'Emergency stop: quick stop, latched until `reset`'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "reset" -d 'Clear a latched safety reaction and re-enable the drives holding where they stand; waits for the outcome'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "params" -d 'The parameters in force: anchors, encoder offsets, their 1-sigma'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "outcome" -d 'One calibration outcome in full (estimate, sigmas, every data problem); `status` lists the newest with their numbers'
complete -c taut -n "__fish_taut_using_subcommand ctl; and __fish_seen_subcommand_from help" -f -a "help" -d 'Print this message or the help of the given subcommand(s)'
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l config -d 'Robot configuration (platform points, noise model). Without it: point-mass platform' -r -F
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l json -d 'Write the diagnosis as JSON (taut-diagnosis v1) to this file' -r -F
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l plot -d 'Write figures (SVG and PNG) into this directory' -r -F
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l report -d 'Write a self-contained HTML report (verdict, tables, figures) to this file, atomically' -r -F
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l tension-at -d 'Where the load cells measure the tension: `platform` (at the attachment, the default) or `anchor` (at the winch)' -r
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l out -d 'Write the final model\'s anchors and offsets with the named effects\' parameters (taut-params v5 TOML, for `taut start --params`) to this file, atomically' -r -F
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l loadcell-sigma -d 'Load-cell noise, 1-sigma of one reading, N (errors-in-variables weights for stretch and sag). Default: `[calibration] loadcell_sigma_n` of --config, else 0 (tensions exact)' -r
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l loadcell-offset -d '1-sigma of each load cell\'s constant offset, N (widens the stretch and sag sigmas). Default: `[calibration] loadcell_offset_n` of --config, else 0 (cells zeroed exactly)' -r
complete -c taut -n "__fish_taut_using_subcommand diagnose" -l tension-side -d 'Also test the load cells against the platform\'s weight and inertia (the tension side: load-cell gain, friction, inertia), with the platform\'s mass `[robot] mass_kg` of --config. Its tests join the length side\'s family (each test\'s level becomes family_alpha / (11 x 3))'
complete -c taut -n "__fish_taut_using_subcommand diagnose" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand diagnose" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand diagnose" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand probe" -l config -d 'Robot configuration (TOML) with a `[can]` table and a `[cable.drive]` per driven cable' -r -F
complete -c taut -n "__fish_taut_using_subcommand probe" -l interface -d 'CAN interface to use instead of the configuration\'s `can.interface`' -r
complete -c taut -n "__fish_taut_using_subcommand probe" -l watch-s -d 'How long to watch the bus after bring-up, s' -r
complete -c taut -n "__fish_taut_using_subcommand probe" -l log -d 'Record the session to this file in `candump -l` format' -r -F
complete -c taut -n "__fish_taut_using_subcommand probe" -l eds-summary -d 'Write, before touching the bus, every object taut reads, writes or maps on each drive with an `eds` as its EDS describes it (checked: exists, access, PDO mapping, length)' -r -F
complete -c taut -n "__fish_taut_using_subcommand probe" -l sim -d 'Probe the simulated robot\'s virtual drives on an in-process bus instead of real hardware (without --config: a 4-cable robot with drives 1..4)'
complete -c taut -n "__fish_taut_using_subcommand probe" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand probe" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand probe" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand export" -l mcap -d 'Write the recording as MCAP to this file, atomically (the only output format)' -r -F
complete -c taut -n "__fish_taut_using_subcommand export" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand export" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand export" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand completions" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand completions" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand completions" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand man" -l dir -d 'Write every page into this directory instead of taut.1 to stdout' -r -F
complete -c taut -n "__fish_taut_using_subcommand man" -s v -l verbose -d 'Say more (`taut start`: also every change of the calibrator\'s stage)'
complete -c taut -n "__fish_taut_using_subcommand man" -s q -l quiet -d 'Say less (`taut start`: no log lines for people, only warnings and the results; `taut ctl`: no progress lines)'
complete -c taut -n "__fish_taut_using_subcommand man" -s h -l help -d 'Print help'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "demo" -d 'Simulate a robot, record its initialisation and excitation, calibrate it, print the results'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "simulate" -d 'Write a recording (cdpr-recording v1) of a simulated robot'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "calibrate" -d 'Calibrate anchors and encoder offsets from any recording (CSV or MCAP), real or simulated'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "start" -d 'Run the robot\'s controller: start-up calibration, hot-swap, operation (--sim: simulated robot)'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "ctl" -d 'Talk to a running `taut start`: status, watch, move, recalibrate, stop, estop, reset, params, outcome'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "diagnose" -d 'Find the physics the ideal model leaves out: name it, model it, show the fit improve'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "probe" -d 'Find every CAN drive, configure its PDOs, print nodes, states, positions and the bus load'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "export" -d 'Convert a recording (cdpr-recording v1) to MCAP for Foxglove, PlotJuggler and rosbag2'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "completions" -d 'Print a shell completion script: taut completions bash > /etc/bash_completion.d/taut'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "man" -d 'Print the manual page (roff): taut man > taut.1; man ./taut.1. With --dir: write taut.1 and one page per subcommand (taut-ctl.1, ...) there'
complete -c taut -n "__fish_taut_using_subcommand help; and not __fish_seen_subcommand_from demo simulate calibrate start ctl diagnose probe export completions man help" -f -a "help" -d 'Print this message or the help of the given subcommand(s)'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "status" -d 'State, goal, calibration (parameter version, worst 1-sigma), drives, load cells, tracker, faults, loop health'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "watch" -d 'Follow what happens (states, phases, faults, parameter swaps, calibration outcomes, goals, resets, loop health), one line per event, until the daemon stops or Ctrl-C'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "move" -d 'Move the platform to X Y Z (m) in a straight line at `motion.move_speed_m_s`'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "recalibrate" -d 'Run the excitation again, recalibrate, hot-swap if better; the platform is brought back to where it was (status and log say where it stopped if it could not be)'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "stop" -d 'Controlled stop: hold, disable the drives, end the daemon'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "estop" -d 'Emergency stop: quick stop, latched until `reset`'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "reset" -d 'Clear a latched safety reaction and re-enable the drives holding where they stand; waits for the outcome'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "params" -d 'The parameters in force: anchors, encoder offsets, their 1-sigma'
complete -c taut -n "__fish_taut_using_subcommand help; and __fish_seen_subcommand_from ctl" -f -a "outcome" -d 'One calibration outcome in full (estimate, sigmas, every data problem); `status` lists the newest with their numbers'

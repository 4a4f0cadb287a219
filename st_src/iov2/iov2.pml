/* iov2.pml -- Promela model of both ends of LinuxCNC's iov2 toolchanger protocol and the link between
 * them, checked with spin by scripts/check-iov2-model.
 *
 *   Host   = FB_Iov2Host.st        (iov2's own state machine + LinuxCNC task's reaction to faults)
 *   Plc    = FB_Iov2Toolchanger.st (the toolchanger end) + the changer it commands
 *   Down   = the link host -> PLC, Up = the link PLC -> host
 *
 * Each ST scan is one d_step here, written in the same order as the ST body, so the model's states are
 * the ST states (table below). Both ends publish their lines as one frame (all bits and numbers of one
 * direction); a link process copies the sender's current frame to the receiver's view whenever it
 * runs. Since spin interleaves processes freely, this covers every delay (0..any scans), every polling
 * period and every skipped frame, with the order of frames kept (a receiver never sees an older frame
 * after a newer one) -- the mb2hal/Modbus behaviour of docs/mb2hal.md.
 *
 * State correspondence (Promela constant -> ST enum value):
 *   H_IDLE  HostIdle           H_PREP  HostPreparing      H_START HostStartChange
 *   H_CHG   HostChanging       H_WABT  HostWaitAbortAck
 *   T_IDLE  TcIdle             T_PREP  TcPreparing        T_START TcStartingChange
 *   T_CHG   TcChanging         T_REFU  TcChangeRefused    T_STOP  TcStopping     T_CANC TcCancelling
 *   F_QUIET FaultQuiet         F_RAISED FaultRaised       F_ACKED FaultAcked
 *   C_NONE/C_PREP/C_START/C_CHG  HostCmdNone/HostCmdPrepare/HostCmdStartChange/HostCmdChange
 * Abstractions: tools are 0..2 and the pocket equals the tool; a toolchanger reason is only its class
 * (R_POS > 0, R_ZERO = 0, R_NEG < 0); emc-reason is ER_OP (any operator/CNC reason), ER_101 or ER_3;
 * the host's results (Done/Error/CommandAborted flags) are reduced to the outcome of the command.
 *
 * Ghost variables (not in the ST) check the invariants: every request carries an id (0..3, wrapping)
 * in the frame; an ack carries the id of the request the PLC answered. Checked:
 *   - no stale ack completes a request: when the host completes a request, the ack's id is the id of
 *     that request (assert in Host);
 *   - both ends agree on completed vs aborted: when the PLC sees an acked request fall it completes
 *     it (no emc-abort) or counts it aborted (emc-abort high); the host must have ended that same
 *     request the same way (assert in Plc);
 *   - the tool number agrees after every completed change (assert in Plc) and at the end;
 *   - a faulted changer never starts a change (assert in Plc);
 *   - deadlock freedom: every state in which nothing can move any more is a proper rest state (both
 *     ends idle, every line low, counters and tools equal; assert in Final) -- and pan's check for
 *     invalid end states;
 *   - no request waits forever: LTL property no_wait_forever (with weak fairness).
 *
 * Configuration (-D on the spin command line): LEGACY (1 = protocol 1 / LinuxCNC 2.10: prepare and
 * change pairs only), SUPPORT_START (iov2 -support-start-change), STRICT (0 = iov2 2.9's own
 * handshake, expected to fail), N_CMDS, N_ABORTS, N_FAULTS (how many commands, operator aborts and
 * changer faults the environment may issue).
 */

#ifndef LEGACY
#define LEGACY 0
#endif
#ifndef SUPPORT_START
#define SUPPORT_START 1
#endif
#ifndef STRICT
#define STRICT 1
#endif
#ifndef N_CMDS
#define N_CMDS 3
#endif
#ifndef N_ABORTS
#define N_ABORTS 1
#endif
#ifndef N_FAULTS
#define N_FAULTS 1
#endif
#ifndef N_TOOLS
#define N_TOOLS 2
#endif

/* host states */
#define H_IDLE  0
#define H_PREP  1
#define H_START 2
#define H_CHG   3
#define H_WABT  4
/* toolchanger states */
#define T_IDLE  0
#define T_PREP  1
#define T_START 2
#define T_CHG   3
#define T_REFU  4
#define T_STOP  5
#define T_CANC  6
/* fault report */
#define F_QUIET  0
#define F_RAISED 1
#define F_ACKED  2
/* host commands */
#define C_NONE  0
#define C_PREP  1
#define C_START 2
#define C_CHG   3
/* outcomes */
#define O_NONE  0
#define O_COMPLETED 1
#define O_SKIPPED 2
#define O_ABORTED 3
#define O_ABORTED_ERR 4
/* toolchanger reason classes */
#define R_POS  1
#define R_ZERO 2
#define R_NEG  3
/* emc-reason */
#define ER_NONE 0
#define ER_OP   1
#define ER_101  2
#define ER_3    3

/* ---- host frame (FB_Iov2Host outputs) and the PLC's view of it ---- */
bit  hPrep, hChange, hStart, hAbort, hFaultAck, hFaulted;
byte hPrepTool;                              /* tool-prep-number */
bit  hPrepId, hStartId, hChangeId, hAbortId; /* ghost: id of the request on the line (toggles) */
bit  hFaultAckId;                            /* ghost: id of the fault report being acked */
bit  dPrep, dChange, dStart, dAbort, dFaultAck, dFaulted;
byte dPrepTool;
bit  dPrepId, dStartId, dChangeId, dAbortId, dFaultAckId;

/* ---- PLC frame (FB_Iov2Toolchanger outputs) and the host's view of it ---- */
bit  pPrepared, pChanged, pStartAck, pAbortAck, pFault;
byte pReason;
bit  pPreparedId, pStartAckId, pChangedId, pAbortAckId, pFaultId; /* ghost: id of what is acked/reported */
bit  uPrepared, uChanged, uStartAck, uAbortAck, uFault;
byte uReason;
bit  uPreparedId, uStartAckId, uChangedId, uAbortAckId, uFaultId;

/* ---- host internals (FB_Iov2Host VARs; emc-reason values are not modelled, see above) ---- */
byte hState = H_IDLE;
byte activeCmd = C_NONE;
byte cmdTool;
bit  cmdEnding, abortWanted, followUpAbort;
byte endOutcome;
byte hFaultReason;            /* FaultReason (class) */
bit  hPrepValid;
byte hPreppedTool, hTool;     /* PreppedTool, ToolNumber */
/* ghost: how the host ended the last request of each pair (1 completed, 0 aborted) and its id, and
   completions the PLC has not seen yet */
bit  hOutPrep, hOutStart, hOutChange, hOutPrepId, hOutStartId, hOutChangeId;
bit  owedPrep, owedStart, owedChange;

/* ---- PLC internals (FB_Iov2Toolchanger VARs) ---- */
byte tState = T_IDLE;
byte faultReport = F_QUIET;
bit  prepareSeen, changeSeen, changerFaultSeen, hostFaultedSeen;
byte pendingTool, changeSeenTool, changeTool, prepTool;
bit  prepareAcked, startAcked, changeAcked, abortAcked, reportPending;
bit  faulted, prepValid;
byte faultReason, toolInSpindle, preppedTool;
bit  pendingPrepId, startSeenId, changeSeenId, abortSeenId, reportId; /* ghost */
bit  startSeen, abortSeen;                                            /* ghost: edge memory for the ids */
bit  cmdPrepare, cmdStart, cmdChange;                                 /* Cmd outputs */

/* ---- the changer (a PLC-side block called each scan after FB_Iov2Toolchanger) ---- */
bit  prepActive, startActive, changeActive, coasting;
bit  prepDone, startDone, changeDone;
bit  cFault;
byte cReason;

/* ---- environment mailboxes (the operator / part program) ---- */
byte cmdReq = C_NONE, cmdReqTool;
bit  abortReq, clearReq, plcClear;
bit  envDone;
byte cmdsLeft = N_CMDS, abortsLeft = N_ABORTS, faultsLeft = N_FAULTS;

/* ---- scheduling: a process runs when something it reads has changed ---- */
bit  hostDirty = 1, plcDirty = 1;

#define DOWN_SYNCED (dPrep == hPrep && dChange == hChange && dStart == hStart && dAbort == hAbort && \
    dFaultAck == hFaultAck && dFaulted == hFaulted && dPrepTool == hPrepTool && dPrepId == hPrepId && \
    dStartId == hStartId && dChangeId == hChangeId && dAbortId == hAbortId && dFaultAckId == hFaultAckId)
#define UP_SYNCED (uPrepared == pPrepared && uChanged == pChanged && uStartAck == pStartAck && \
    uAbortAck == pAbortAck && uFault == pFault && uReason == pReason && uPreparedId == pPreparedId && \
    uStartAckId == pStartAckId && uChangedId == pChangedId && uAbortAckId == pAbortAckId && uFaultId == pFaultId)
#define MOVING (prepActive || startActive || changeActive || coasting)
#define CHANGER_STOPPED (!MOVING)
#define QUIESCENT (envDone && !hostDirty && !plcDirty && DOWN_SYNCED && UP_SYNCED && !MOVING)

#define HOST_BUSY (activeCmd != C_NONE || abortWanted || followUpAbort || hState != H_IDLE)

/* state snapshots, to know whether a scan changed anything (then it runs again at once) */
#define HOST_PACK (hState + 8*(activeCmd + 4*(cmdEnding + 2*(abortWanted + 2*(followUpAbort + \
    2*(hPrepValid + 2*(hPreppedTool + 4*(hTool + 4*(hFaulted + 2*(hFaultAck + 2*(hFaultReason + \
    4*(endOutcome + 8*(hPrepTool + 4*(cmdTool + 4*(hPrepId + 2*(hStartId + 2*(hChangeId + \
    2*(hAbortId + 2*hFaultAckId))))))))))))))))))
#define PLC_PACK (tState + 8*(faultReport + 4*(prepareSeen + 2*(changeSeen + 2*(changerFaultSeen + \
    2*(hostFaultedSeen + 2*(pendingTool + 4*(changeSeenTool + 4*(changeTool + 4*(prepareAcked + \
    2*(startAcked + 2*(changeAcked + 2*(abortAcked + 2*(reportPending + 2*(faulted + 2*(prepValid + \
    2*(faultReason + 4*(toolInSpindle + 4*(preppedTool + 4*prepTool)))))))))))))))))))
#define PLC_PACK2 (pendingPrepId + 2*(startSeenId + 2*(changeSeenId + 2*(abortSeenId + 2*(reportId + \
    2*(startSeen + 2*(abortSeen + 2*(cmdPrepare + 2*(cmdStart + 2*(cmdChange + 2*(prepActive + \
    2*(startActive + 2*(changeActive + 2*(coasting + 2*(prepDone + 2*(startDone + 2*(changeDone + \
    2*(pFault + 2*pReason))))))))))))))))))

hidden int before1, before2;

/* ======================= FB_Iov2Host, one call (numbers = LastTransition) ======================= */
#define P_SET (!STRICT || !uPrepared)
#define S_SET (!STRICT || !uStartAck)
#define C_SET (!STRICT || !uChanged)
#define A_SET (!STRICT || !uAbortAck)
#define RAISE_ABORT hState = H_WABT; hAbortId = !hAbortId

inline host_scan() {
    /* toolchanger fault lines (protocol 2) */
    if
    :: LEGACY -> hFaultAck = 0
    :: !LEGACY && uFault -> hFaultReason = uReason; hFaultAck = 1; hFaulted = 1; hFaultAckId = uFaultId
    :: !LEGACY && !uFault -> hFaultAck = 0;
        if
        :: clearReq -> hFaulted = 0; hFaultReason = R_ZERO
        :: else -> skip
        fi
    fi;
    clearReq = 0;
    /* commands (the environment sends one only when no command is active) */
    if
    :: cmdReq != C_NONE -> assert(activeCmd == C_NONE); activeCmd = cmdReq; cmdTool = cmdReqTool;
        cmdEnding = 0; cmdReq = C_NONE
    :: else -> skip
    fi;
    if
    :: abortReq -> abortWanted = 1; abortReq = 0
    :: else -> skip
    fi;
    if
    :: hState == H_IDLE ->
        if
        :: abortWanted && LEGACY ->                                                           /* 1 */
            abortWanted = 0;
            if :: activeCmd != C_NONE -> activeCmd = C_NONE; cmdEnding = 0 :: else -> skip fi
        :: abortWanted && !LEGACY ->
            if
            :: A_SET && P_SET && S_SET && C_SET ->                                            /* 2 */
                abortWanted = 0;
                if
                :: activeCmd != C_NONE && !cmdEnding -> cmdEnding = 1; endOutcome = O_ABORTED
                :: else -> skip
                fi;
                RAISE_ABORT
            :: else -> skip
            fi
        :: !abortWanted && activeCmd == C_PREP && !cmdEnding && P_SET ->                     /* 3 */
            hPrepTool = cmdTool; hState = H_PREP; hPrepId = !hPrepId
        :: !abortWanted && activeCmd == C_START && !cmdEnding && (LEGACY || !SUPPORT_START) -> /* 4 */
            activeCmd = C_NONE
        :: !abortWanted && activeCmd == C_START && !cmdEnding && !LEGACY && SUPPORT_START && S_SET -> /* 5 */
            hState = H_START; hStartId = !hStartId
        :: !abortWanted && activeCmd == C_CHG && !cmdEnding && (!hPrepValid || hPreppedTool == hTool) -> /* 6 */
            activeCmd = C_NONE
        :: !abortWanted && activeCmd == C_CHG && !cmdEnding && hPrepValid && hPreppedTool != hTool && C_SET -> /* 7 */
            hState = H_CHG; hChangeId = !hChangeId
        :: else -> skip
        fi
    :: hState == H_PREP ->
        if
        :: abortWanted && LEGACY ->                                                           /* 8 */
            abortWanted = 0; activeCmd = C_NONE; hState = H_IDLE;
            hOutPrep = 0; hOutPrepId = hPrepId
        :: abortWanted && !LEGACY && A_SET && S_SET && C_SET ->                               /* 9 */
            abortWanted = 0; cmdEnding = 1; endOutcome = O_ABORTED; RAISE_ABORT;
            hOutPrep = 0; hOutPrepId = hPrepId
        :: !(abortWanted && (LEGACY || (A_SET && S_SET && C_SET))) && uPrepared ->            /* 10 */
            assert(uPreparedId == hPrepId);          /* no stale ack completes a request */
            hPreppedTool = cmdTool; hPrepValid = 1; activeCmd = C_NONE; hState = H_IDLE;
            hOutPrep = 1; hOutPrepId = hPrepId; owedPrep = 1
        :: else -> skip
        fi
    :: hState == H_START ->
        if
        :: abortWanted && A_SET && P_SET && C_SET ->                                          /* 11 */
            abortWanted = 0; cmdEnding = 1; endOutcome = O_ABORTED; RAISE_ABORT;
            hOutStart = 0; hOutStartId = hStartId
        :: !(abortWanted && A_SET && P_SET && C_SET) && uStartAck ->                          /* 12 */
            assert(uStartAckId == hStartId);
            activeCmd = C_NONE; hState = H_IDLE;
            hOutStart = 1; hOutStartId = hStartId; owedStart = 1
        :: !(abortWanted && A_SET && P_SET && C_SET) && !uStartAck && hFaulted && hFaultReason != R_POS && A_SET && P_SET && C_SET ->                                                      /* 13 */
            cmdEnding = 1;
            if :: hFaultReason == R_NEG -> endOutcome = O_ABORTED_ERR :: else -> endOutcome = O_ABORTED fi;
            RAISE_ABORT;
            hOutStart = 0; hOutStartId = hStartId
        :: else -> skip
        fi
    :: hState == H_CHG ->
        if
        :: abortWanted && LEGACY ->                                                           /* 14 */
            abortWanted = 0; activeCmd = C_NONE; hState = H_IDLE;
            hOutChange = 0; hOutChangeId = hChangeId
        :: abortWanted && !LEGACY && A_SET && P_SET && S_SET ->                               /* 15 */
            abortWanted = 0; cmdEnding = 1; endOutcome = O_ABORTED; RAISE_ABORT;
            hOutChange = 0; hOutChangeId = hChangeId
        :: !(abortWanted && (LEGACY || (A_SET && P_SET && S_SET))) && hFaulted && A_SET && P_SET && S_SET -> /* 16 */
            cmdEnding = 1;
            if
            :: hFaultReason == R_POS -> endOutcome = O_SKIPPED
            :: hFaultReason == R_ZERO -> endOutcome = O_ABORTED; followUpAbort = 1
            :: hFaultReason == R_NEG -> endOutcome = O_ABORTED_ERR; followUpAbort = 1
            fi;
            RAISE_ABORT;
            hOutChange = 0; hOutChangeId = hChangeId
        :: !(abortWanted && (LEGACY || (A_SET && P_SET && S_SET))) && !(hFaulted && A_SET && P_SET && S_SET) && uChanged ->                                                                     /* 17 */
            assert(uChangedId == hChangeId);
            hTool = hPreppedTool; hPrepValid = 0; hPrepTool = 0;
            activeCmd = C_NONE; hState = H_IDLE;
            hOutChange = 1; hOutChangeId = hChangeId; owedChange = 1
        :: else -> skip
        fi
    :: hState == H_WABT ->
        if
        :: uAbortAck ->                                                                       /* 18 */
            assert(uAbortAckId == hAbortId);
            if
            :: followUpAbort -> followUpAbort = 0; abortWanted = 1
            :: else ->
                if :: cmdEnding -> activeCmd = C_NONE; cmdEnding = 0; endOutcome = O_NONE :: else -> skip fi
            fi;
            hState = H_IDLE
        :: else -> skip
        fi
    fi;
    hPrep = (hState == H_PREP);
    hStart = (hState == H_START);
    hChange = (hState == H_CHG);
    hAbort = (hState == H_WABT)
}

/* ========== FB_Iov2Toolchanger + the changer, one scan (numbers = LastTransition) ========== */
#define ABORT_NEW (dAbort && !abortAcked)

inline plc_scan() {
    /* latch on first sight */
    if
    :: dPrep && (!prepareSeen || (!prepareAcked && dPrepTool != pendingTool)) ->
        pendingTool = dPrepTool; pendingPrepId = dPrepId
    :: else -> skip
    fi;
    if :: dChange && !changeSeen -> changeSeenTool = dPrepTool; changeSeenId = dChangeId :: else -> skip fi;
    if :: dStart && !startSeen -> startSeenId = dStartId :: else -> skip fi;
    if :: dAbort && !abortSeen -> abortSeenId = dAbortId :: else -> skip fi;
    prepareSeen = dPrep; changeSeen = dChange; startSeen = dStart; abortSeen = dAbort;
    /* requests that are low: completed, or aborted if emc-abort is high; both ends must agree */
    if
    :: !dPrep && prepareAcked ->
        assert(hOutPrepId == pendingPrepId);
        if
        :: dAbort -> assert(hOutPrep == 0)
        :: else -> assert(hOutPrep == 1 && owedPrep); owedPrep = 0;
            preppedTool = pendingTool; prepValid = 1
        fi;
        prepareAcked = 0
    :: else -> skip
    fi;
    if
    :: !dStart && startAcked ->
        assert(hOutStartId == startSeenId);
        if
        :: dAbort -> assert(hOutStart == 0)
        :: else -> assert(hOutStart == 1 && owedStart); owedStart = 0
        fi;
        startAcked = 0
    :: else -> skip
    fi;
    if
    :: !dChange && changeAcked ->
        assert(hOutChangeId == changeSeenId);
        if
        :: dAbort -> assert(hOutChange == 0)
        :: else -> assert(hOutChange == 1 && owedChange); owedChange = 0;
            toolInSpindle = changeTool; prepValid = 0;
            assert(toolInSpindle == hTool)        /* tool number agrees after a completed change */
        fi;
        changeAcked = 0
    :: else -> skip
    fi;
    if :: !dAbort -> abortAcked = 0 :: else -> skip fi;
    /* fault latch */
    if :: cFault && !changerFaultSeen -> faulted = 1; faultReason = cReason; reportPending = 1 :: else -> skip fi;
    changerFaultSeen = cFault;
    if
    :: hostFaultedSeen && !dFaulted && faulted ->
        if :: cFault -> faultReason = cReason; reportPending = 1 :: else -> faulted = 0 fi
    :: else -> skip
    fi;
    hostFaultedSeen = dFaulted;
    if :: plcClear && !cFault -> faulted = 0 :: else -> skip fi;
    plcClear = 0;
    if :: !faulted -> reportPending = 0 :: else -> skip fi;
    /* fault report */
    if
    :: faultReport == F_QUIET && reportPending && faulted && !changeAcked && !dFaultAck ->   /* 24 */
        pReason = faultReason; reportPending = 0; faultReport = F_RAISED; reportId = !reportId
    :: faultReport == F_RAISED && dFaultAck ->                                              /* 25 */
        assert(dFaultAckId == reportId);          /* no stale fault ack */
        faultReport = F_ACKED
    :: faultReport == F_ACKED && !dFaultAck -> faultReport = F_QUIET                        /* 26 */
    :: else -> skip
    fi;
    /* main machine */
    if
    :: tState == T_IDLE ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 1 */
        :: !ABORT_NEW && dChange && !changeAcked ->
            if :: prepValid -> changeTool = preppedTool :: else -> changeTool = changeSeenTool fi;
            if :: faulted -> tState = T_REFU :: else -> tState = T_CHG fi                  /* 2, 3 */
        :: !ABORT_NEW && !(dChange && !changeAcked) && dStart && !startAcked -> tState = T_START /* 4 */
        :: !ABORT_NEW && !(dChange && !changeAcked) && !(dStart && !startAcked) && dPrep && !prepareAcked ->
            prepTool = pendingTool; tState = T_PREP                                         /* 5 */
        :: else -> skip
        fi
    :: tState == T_PREP ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 6 */
        :: !ABORT_NEW && !dPrep -> tState = T_CANC                                          /* 7 */
        :: !ABORT_NEW && dPrep && prepTool != pendingTool -> tState = T_CANC                /* 27 */
        :: !ABORT_NEW && dPrep && prepTool == pendingTool && (faulted || prepDone) ->
            prepareAcked = 1; tState = T_IDLE                                               /* 8, 9 */
        :: else -> skip
        fi
    :: tState == T_START ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 10 */
        :: !ABORT_NEW && !dStart -> tState = T_CANC                                         /* 11 */
        :: !ABORT_NEW && dStart && (faulted || startDone) -> startAcked = 1; tState = T_IDLE /* 12, 13 */
        :: else -> skip
        fi
    :: tState == T_CHG ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 14 */
        :: !ABORT_NEW && !dChange -> tState = T_CANC                                        /* 15 */
        :: !ABORT_NEW && dChange && faulted -> tState = T_REFU                              /* 16 */
        :: !ABORT_NEW && dChange && !faulted && changeDone -> changeAcked = 1; tState = T_IDLE /* 17 */
        :: else -> skip
        fi
    :: tState == T_REFU ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 18 */
        :: !ABORT_NEW && !dChange -> tState = T_CANC                                        /* 19 */
        :: !ABORT_NEW && dChange && !faulted -> tState = T_CHG                              /* 20 */
        :: else -> skip
        fi
    :: tState == T_STOP ->
        if
        :: CHANGER_STOPPED ->                                                               /* 21 */
            if :: dAbort -> abortAcked = 1 :: else -> skip fi;
            tState = T_IDLE
        :: else -> skip
        fi
    :: tState == T_CANC ->
        if
        :: ABORT_NEW -> tState = T_STOP                                                     /* 22 */
        :: !ABORT_NEW && CHANGER_STOPPED -> tState = T_IDLE                                 /* 23 */
        :: else -> skip
        fi
    fi;
    /* outputs */
    pPrepared = prepareAcked && dPrep;       pPreparedId = pendingPrepId;
    pStartAck = startAcked && dStart;        pStartAckId = startSeenId;
    pChanged = changeAcked && dChange;       pChangedId = changeSeenId;
    pAbortAck = abortAcked && dAbort;        pAbortAckId = abortSeenId;
    pFault = (faultReport == F_RAISED);      pFaultId = reportId;
    cmdPrepare = (tState == T_PREP && !faulted);
    cmdStart = (tState == T_START && !faulted);
    cmdChange = (tState == T_CHG && !faulted);
    /* the changer, called after FB_Iov2Toolchanger in the same scan (PLCopen-like: Done drops with
       its command; a command that drops, or a fault, stops the work, which takes time: coasting) */
    if :: !cmdPrepare -> prepDone = 0 :: else -> skip fi;
    if :: !cmdStart -> startDone = 0 :: else -> skip fi;
    if :: !cmdChange -> changeDone = 0 :: else -> skip fi;
    if :: prepActive && (!cmdPrepare || cFault) -> prepActive = 0; coasting = 1 :: else -> skip fi;
    if :: startActive && (!cmdStart || cFault) -> startActive = 0; coasting = 1 :: else -> skip fi;
    if :: changeActive && (!cmdChange || cFault) -> changeActive = 0; coasting = 1 :: else -> skip fi;
    if :: cmdPrepare && !prepActive && !prepDone && !cFault -> prepActive = 1 :: else -> skip fi;
    if :: cmdStart && !startActive && !startDone && !cFault -> startActive = 1 :: else -> skip fi;
    if
    :: cmdChange && !changeActive && !changeDone && !cFault ->
        assert(!faulted);                     /* a faulted changer never starts a change */
        changeActive = 1
    :: else -> skip
    fi
}

active proctype Host() {
    do
    :: d_step {
        hostDirty ->
        hostDirty = 0;
        before1 = HOST_PACK;
        host_scan();
        if :: before1 != HOST_PACK -> hostDirty = 1 :: else -> skip fi;
        before1 = 0
       }
    :: QUIESCENT -> break
    od;
    /* rest state: deadlock freedom and agreement at the end */
    assert(hState == H_IDLE && activeCmd == C_NONE && !abortWanted && !followUpAbort);
    assert(tState == T_IDLE && (faultReport == F_QUIET || LEGACY));  /* protocol 1: fault line unwired */
    assert(!hPrep && !hChange && !hStart && !hAbort && !hFaultAck);
    assert(!pPrepared && !pChanged && !pStartAck && !pAbortAck && (!pFault || LEGACY));
    assert(!owedPrep && !owedStart && !owedChange);   /* every completion seen by both ends */
    assert(hTool == toolInSpindle);
    assert(hPrepValid == prepValid && (!prepValid || hPreppedTool == preppedTool))
}

active proctype Plc() {
    do
    :: d_step {
        plcDirty ->
        plcDirty = 0;
        before1 = PLC_PACK; before2 = PLC_PACK2;
        plc_scan();
        if :: before1 != PLC_PACK || before2 != PLC_PACK2 -> plcDirty = 1 :: else -> skip fi;
        before1 = 0; before2 = 0
       }
    :: QUIESCENT -> break
    od
}

/* the link host -> PLC: copies the host's current frame (any delay, polling, skipped frames) */
active proctype Down() {
    do
    :: d_step {
        !DOWN_SYNCED ->
        dPrep = hPrep; dChange = hChange; dStart = hStart; dAbort = hAbort; dFaultAck = hFaultAck;
        dFaulted = hFaulted; dPrepTool = hPrepTool; dPrepId = hPrepId; dStartId = hStartId;
        dChangeId = hChangeId; dAbortId = hAbortId; dFaultAckId = hFaultAckId;
        plcDirty = 1
       }
    :: QUIESCENT -> break
    od
}

/* the link PLC -> host */
active proctype Up() {
    do
    :: d_step {
        !UP_SYNCED ->
        uPrepared = pPrepared; uChanged = pChanged; uStartAck = pStartAck; uAbortAck = pAbortAck;
        uFault = pFault; uReason = pReason; uPreparedId = pPreparedId; uStartAckId = pStartAckId;
        uChangedId = pChangedId; uAbortAckId = pAbortAckId; uFaultId = pFaultId;
        hostDirty = 1
       }
    :: QUIESCENT -> break
    od
}

/* the changer's own progress: work finishes (unless faulted), a stop ends */
active proctype Changer() {
    do
    :: d_step { prepActive && !cFault -> prepActive = 0; prepDone = 1; plcDirty = 1 }
    :: d_step { startActive && !cFault -> startActive = 0; startDone = 1; plcDirty = 1 }
    :: d_step { changeActive && !cFault -> changeActive = 0; changeDone = 1; plcDirty = 1 }
    :: d_step { coasting -> coasting = 0; plcDirty = 1 }
    :: QUIESCENT -> break
    od
}

/* the operator and the part program: commands, aborts, changer faults and clears, then stop */
active proctype Env() {
    do
    :: atomic {
        cmdsLeft > 0 && activeCmd == C_NONE && cmdReq == C_NONE ->
        if
        :: cmdReqTool = 0; cmdReq = C_PREP
        :: cmdReqTool = 1; cmdReq = C_PREP
#if N_TOOLS > 2
        :: cmdReqTool = 2; cmdReq = C_PREP
#endif
#if SUPPORT_START && !LEGACY
        :: cmdReq = C_START
#endif
        :: cmdReq = C_CHG
        fi;
        cmdsLeft--; hostDirty = 1
       }
    :: d_step { abortsLeft > 0 && !abortReq -> abortReq = 1; abortsLeft--; hostDirty = 1 }
    :: atomic {
        faultsLeft > 0 && !cFault ->
        if
        :: cReason = R_POS
        :: cReason = R_ZERO
        :: cReason = R_NEG
        fi;
        cFault = 1; faultsLeft--; plcDirty = 1
       }
    :: d_step { cFault -> cFault = 0; plcDirty = 1 }
    :: d_step { !cFault && !plcClear && faulted -> plcClear = 1; plcDirty = 1 }
    :: d_step { !clearReq && hFaulted && !uFault -> clearReq = 1; hostDirty = 1 }
    /* the environment may stop at any time; with protocol 1 a fault has no line to iov2, so the
       operator has to clear it (else a refused M6 waits, as it would on the machine) */
    :: cmdReq == C_NONE && !abortReq && !clearReq && !plcClear && (!LEGACY || (!cFault && !faulted)) ->
        envDone = 1; break
    od;
    (QUIESCENT)
}

/* no request waits forever: whatever either end is busy with, both ends are eventually at rest */
ltl no_wait_forever { [] ((HOST_BUSY || tState != T_IDLE) -> <> (!HOST_BUSY && tState == T_IDLE)) }

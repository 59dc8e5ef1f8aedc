"use strict";
// Loads the skill model's NodeSet2 files (models/) into a node-opcua address space next to
// ns0, DI, IA and Robotics from node-opcua-nodesets, checks a few types by browse name and
// instantiates some of them. Prints OK; exits non-zero on any problem.
// usage: node node_load_skill_models.js MODELS_DIR

// node-opcua logs with console.log: keep stdout for this script's own lines.
const stdoutWrite = process.stdout.write.bind(process.stdout);
const out = (line) => stdoutWrite(line + "\n");
process.stdout.write = process.stderr.write.bind(process.stderr);

const path = require("path");
const fs = require("fs");
const { AddressSpace } = require("node-opcua-address-space");
const { generateAddressSpace } = require("node-opcua-address-space/nodeJS");
const { nodesets } = require("node-opcua-nodesets");

const modelsDir = process.argv[2];
if (!modelsDir || !fs.existsSync(modelsDir)) {
    console.error("usage: node node_load_skill_models.js MODELS_DIR");
    process.exit(2);
}

const FILES = [
    "Pnp.Skills.NodeSet2.xml",
    "Pnp.Skills.Robotics.NodeSet2.xml",
    "Pnp.Skills.ToolChanger.NodeSet2.xml",
    "Pnp.Skills.Composite.NodeSet2.xml",
    "Pnp.Skills.Demo.NodeSet2.xml",
];

let failures = 0;
function check(ok, what) {
    if (!ok) {
        failures++;
        out(`FAIL ${what}`);
    }
}

// A child below `node` by browse-name path ("ns:Name" or "Name").
function child(node, names) {
    for (const name of names) {
        if (!node) return null;
        const m = /^(\d+):(.*)$/.exec(name);
        node = m ? node.getChildByName(m[2], Number(m[1])) : node.getChildByName(name, 0);
    }
    return node;
}

async function main() {
    const addressSpace = AddressSpace.create();
    const files = [nodesets.standard, nodesets.di, nodesets.ia, nodesets.robotics].concat(
        FILES.map((f) => path.join(modelsDir, f)));
    // node-opcua reports problems of a NodeSet (unknown nodes, bad values) as log lines:
    // any line logged while loading is a failure.
    const logged = [];
    const saved = [console.log, console.warn, console.error];
    console.log = console.warn = console.error = (...args) => logged.push(args.join(" "));
    try {
        await generateAddressSpace(addressSpace, files);
    } finally {
        [console.log, console.warn, console.error] = saved;
    }
    for (const line of logged) if (line.trim()) check(false, `loader said: ${line}`);

    const ns = (uri) => {
        const i = addressSpace.getNamespaceIndex(uri);
        check(i > 0, `namespace ${uri} loaded`);
        return i;
    };
    const di = ns("http://opcfoundation.org/UA/DI/");
    const base = ns("urn:pnp:ua:skills");
    const rob = ns("urn:pnp:ua:skills:robotics");
    const tc = ns("urn:pnp:ua:skills:toolchanger");
    const comp = ns("urn:pnp:ua:skills:composite");
    const demo = ns("urn:pnp:ua:skills:demo");

    const program = addressSpace.findObjectType("ProgramStateMachineType");
    const skillType = addressSpace.findObjectType("SkillType", base);
    check(skillType && skillType.isAbstract, "SkillType exists and is abstract");
    check(skillType && skillType.isSubtypeOf(program), "SkillType is a ProgramStateMachineType");
    check(skillType && skillType.nodeId.toString() === `ns=${base};i=1001`, "SkillType id");
    const types = [
        [base, "ISkillControllerType", "BaseInterfaceType"],
        [base, "SkillTransitionEventType", "ProgramTransitionEventType"],
        [base, "MoveGripperSkillType", "SkillType"],
        [base, "GraspGripperSkillType", "SkillType"],
        [base, "ParallelGripPointType", "GripPointType"],
        [rob, "CartesianLinearForceMoveSkillType", "SkillType"],
        [rob, "JointPtpMoveSkillType", "SkillType"],
        [rob, "PositionStreamSkillType", "SkillType"],
        [rob, "SkillMotionDeviceType", "MotionDeviceType"],
        [tc, "ChangeToolSkillType", "SkillType"],
        [comp, "PickAndPlaceSkillType", "SkillType"],
        [demo, "DelaySkillType", "SkillType"],
    ];
    for (const [n, name, superName] of types) {
        const t = addressSpace.findObjectType(name, n) || addressSpace.findEventType(name, n);
        check(!!t, `${name} found`);
        if (!t) continue;
        let s = t;
        while (s && s.browseName.name !== superName) s = s.subtypeOfObj;
        check(!!s, `${name} is a subtype of ${superName}`);
    }
    const result = addressSpace.findDataType("SkillResultCode", base);
    check(result && result.isEnumeration(), "SkillResultCode is an enumeration");

    // Instantiate a gripper skill and a force move below Objects.
    const objects = addressSpace.rootFolder.objects;
    const grip = addressSpace.findObjectType("MoveGripperSkillType", base).instantiate({
        browseName: { name: "MoveGripper", namespaceIndex: 1 },
        organizedBy: objects,
    });
    for (const p of [["CurrentState"], ["Start"], ["Reset"], ["FinalResultData"],
                     [`${di}:ParameterSet`], [`${di}:ParameterSet`, `${base}:Width`],
                     [`${di}:ParameterSet`, `${base}:Force`], [`${di}:Lock`],
                     [`${di}:Lock`, `${di}:InitLock`], [`${base}:Name`]])
        check(!!child(grip, p), `MoveGripper/${p.join("/")}`);
    const delay = addressSpace.findObjectType("DelaySkillType", demo).instantiate({
        browseName: { name: "Delay", namespaceIndex: 1 },
        organizedBy: objects,
    });
    check(!!child(delay, [`${di}:ParameterSet`, `${demo}:DurationMs`]),
          "Delay/ParameterSet/DurationMs");

    // Parameters of the supertypes are merged below the subtype's ParameterSet. (node-opcua
    // 2.186 does not merge an interface's nested declarations, e.g. TargetPosition from
    // ICartesianMoveSkillParameterType below ParameterSet; our server does.)
    const forceType = addressSpace.findObjectType("CartesianLinearForceMoveSkillType", rob);
    const force = forceType.instantiate({
        browseName: { name: "ForceMove", namespaceIndex: 1 },
        organizedBy: objects,
    });
    for (const p of ["MaxForce", "MaxVelocity", "MaxAcceleration", "ToolFrame"])
        check(!!child(force, [`${di}:ParameterSet`, `${rob}:${p}`]),
              `ForceMove/ParameterSet/${p}`);
    check(!!child(force, ["FinalResultData", `${base}:Result`]),
          "ForceMove/FinalResultData/Result");
    // A skill controller: the interface's Skills folder and Name.
    const arm = addressSpace.findObjectType("SkillMotionDeviceType", rob).instantiate({
        browseName: { name: "Arm", namespaceIndex: 1 },
        organizedBy: objects,
    });
    check(!!child(arm, [`${base}:Skills`]), "Arm/Skills");
    check(!!child(arm, [`${base}:Name`]), "Arm/Name");
    check(!!child(arm, [`${rob}:WorldToRobotBase`]), "Arm/WorldToRobotBase");

    if (failures) {
        out(`${failures} check(s) failed`);
        process.exit(1);
    }
    out("OK");
    addressSpace.dispose();
}

main().catch((e) => {
    out(`FAIL ${e && e.stack ? e.stack : e}`);
    process.exit(1);
});

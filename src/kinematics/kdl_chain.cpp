#include "kinematics/kdl_chain.hpp"

#include <exception>
#include <filesystem>
#include <fstream>
#include <kdl/chainfksolverpos_recursive.hpp>
#include <kdl/tree.hpp>
#include <kdl_parser/kdl_parser.hpp>
#include <sstream>

namespace pnp::kinematics {

KDL::Chain toKdlChain(const RobotModel& model) {
    KDL::Chain chain;
    for (int i = 0; i < kAxes; ++i) {
        const DhRow& r = model.dh[i];
        // Composed from elementary frames rather than KDL::Frame::DH, so the cross-check
        // does not rest on one more reading of the DH convention.
        const KDL::Frame tip = KDL::Frame(KDL::Rotation::RotZ(r.thetaOffset)) *
                               KDL::Frame(KDL::Vector(0.0, 0.0, r.d)) *
                               KDL::Frame(KDL::Vector(r.a, 0.0, 0.0)) *
                               KDL::Frame(KDL::Rotation::RotX(r.alpha));
        chain.addSegment(
            KDL::Segment("link" + std::to_string(i + 1), KDL::Joint(KDL::Joint::RotZ), tip));
    }
    return chain;
}

Result<KDL::Chain> chainFromUrdf(const std::string& path, const std::string& baseLink,
                                 const std::string& tipLink) {
    try {
        std::error_code ec;
        if (!std::filesystem::is_regular_file(path, ec)) {
            return Error{ErrorCode::kFileNotFound, "URDF file not found: " + path};
        }
        std::ifstream in(path);
        if (!in) return Error{ErrorCode::kFileNotFound, "cannot read URDF file: " + path};
        std::ostringstream text;
        text << in.rdbuf();
        KDL::Tree tree;
        if (!kdl_parser::treeFromString(text.str(), tree)) {
            return Error{ErrorCode::kParseError, "cannot parse URDF into a KDL tree: " + path};
        }
        const auto& segments = tree.getSegments();
        for (const std::string& link : {baseLink, tipLink}) {
            if (segments.find(link) == segments.end()) {
                return Error{ErrorCode::kLinkNotFound, "link '" + link + "' not in " + path};
            }
        }
        KDL::Chain chain;
        if (!tree.getChain(baseLink, tipLink, chain)) {
            return Error{ErrorCode::kLinkNotFound,
                         "no chain from '" + baseLink + "' to '" + tipLink + "' in " + path};
        }
        return chain;
    } catch (const std::exception& e) {
        // urdfdom / kdl_parser may throw on malformed input; the API promises no exceptions.
        return Error{ErrorCode::kParseError, "URDF " + path + ": " + e.what()};
    }
}

Eigen::Isometry3d toEigen(const KDL::Frame& f) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) t.matrix()(r, c) = f.M(r, c);
        t.matrix()(r, 3) = f.p(r);
    }
    return t;
}

KDL::Frame toKdl(const Eigen::Isometry3d& t) {
    const auto& m = t.matrix();
    return KDL::Frame(KDL::Rotation(m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2), m(2, 0),
                                    m(2, 1), m(2, 2)),
                      KDL::Vector(m(0, 3), m(1, 3), m(2, 3)));
}

Result<Eigen::Isometry3d> forwardKdl(const KDL::Chain& chain, std::span<const double> q) {
    if (q.size() != chain.getNrOfJoints()) {
        return Error{ErrorCode::kInvalidArgument,
                     "chain has " + std::to_string(chain.getNrOfJoints()) + " joints, got " +
                         std::to_string(q.size()) + " values"};
    }
    KDL::JntArray jq(chain.getNrOfJoints());
    for (size_t i = 0; i < q.size(); ++i) jq(i) = q[i];
    KDL::ChainFkSolverPos_recursive solver(chain);
    KDL::Frame f;
    if (solver.JntToCart(jq, f) < 0) {
        return Error{ErrorCode::kInvalidArgument, "KDL forward kinematics failed"};
    }
    return toEigen(f);
}

}  // namespace pnp::kinematics

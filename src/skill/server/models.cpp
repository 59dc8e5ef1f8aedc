// Loading the skill models and resolving their nodes in an address space.
#include <filesystem>

#include "skill/server/controller.hpp"
#include "ua/server/nodeset_xml.hpp"

namespace pnp::skill::server {

void loadSkillModels(ua::server::AddressSpace& space, const std::vector<std::string_view>& uris) {
    // Our files find each other (and DI, Robotics) by ModelUri on the search path.
    auto searchPath = ua::server::defaultNodeSetSearchPath();
    searchPath.insert(searchPath.begin(), modelsDirectory());
    for (std::string_view uri : uris) {
        if (ua::server::isModelLoaded(space, uri)) continue;
        const std::filesystem::path file = modelFile(uri);
        if (file.empty()) throw SkillError("no skill model with the URI " + std::string(uri));
        ua::server::loadNodeSetXml(space, file, searchPath);
    }
}

ua::NodeId resolve(const ua::server::AddressSpace& space, const ModelNode& node) {
    auto ns = space.namespaceIndex(node.uri);
    if (!ns)
        throw SkillError("the model " + std::string(node.uri) + " of " + std::string(node.name) +
                         " is not loaded");
    ua::NodeId id(*ns, node.id);
    if (!space.contains(id))
        throw SkillError(std::string(node.name) + " (" + id.toString() + ") is not in the model " +
                         std::string(node.uri));
    return id;
}

}  // namespace pnp::skill::server
